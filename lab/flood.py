"""Ground-link floods: the seeded hostile-datagram generator, a flood sender, and ``smcpilot bench flood``.

:class:`Fuzzer` builds hostile datagrams by class, seeded (random bytes, truncated MAVLink 1 and 2
frames, bad CRCs, valid-CRC frames with NaN / ±inf / huge fields, frames for other systems);
``tests/test_fuzz.py`` sends them during lockstep and real-time flights, :func:`send_flood` at a
fixed rate with the heartbeat flood of many systems beside them.

``smcpilot bench flood`` (docs/security.md, "Measured") flies the same real-time flight clean and flooded,
back to back, ``--pairs`` times, while a well-behaved ground station sends a command every half
second and times its ``COMMAND_ACK``; it prints the loop's figures (overruns, p99 lateness), the
flooded track's deviation from the clean one, the command answer times, and what the FC's
ground-link budget deferred and dropped, as ratios against the clean run. It measures, never
asserts.
"""

from __future__ import annotations

import argparse
import bisect
import contextlib
import math
import os
import platform
import random
import socket
import subprocess
import sys
import tempfile
import threading
import time
from collections import Counter
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path

from pymavlink.dialects.v10 import ardupilotmega as M1
from pymavlink.dialects.v20 import ardupilotmega as M

from smcpilot.protocol import SIM_COMPONENT_ID

LOOPBACK = "127.0.0.1"
FC_SYSID = 1
NAN, INF = math.nan, math.inf
HOSTILE_FLOATS = (NAN, INF, -INF)
HUGE = (1e30, -1e30, 3.4e38)
FOREIGN_SYSID = 77  # not the vehicle


# -- where things listen ---------------------------------------------------------------------------
def udp_ports(pid: int) -> list[int]:
    """The UDP ports process ``pid`` has sockets bound to (Linux /proc)."""
    inodes = set()
    for fd in os.listdir(f"/proc/{pid}/fd"):
        with contextlib.suppress(OSError):
            target = os.readlink(f"/proc/{pid}/fd/{fd}")
            if target.startswith("socket:["):
                inodes.add(target[8:-1])
    ports = []
    with open("/proc/net/udp", encoding="ascii") as f:
        next(f)
        for line in f:
            cols = line.split()
            if cols[9] in inodes:
                ports.append(int(cols[1].split(":")[1], 16))
    return ports


# -- the fuzzer ------------------------------------------------------------------------------------
@dataclass
class Fuzzer:
    """Builds hostile datagrams by class, seeded. ``sent`` counts datagrams by (target, class)."""

    seed: int
    rng: random.Random = field(init=False)
    sent: Counter = field(default_factory=Counter)

    def __post_init__(self) -> None:
        self.rng = random.Random(self.seed)
        self.enc = M.MAVLink(None, srcSystem=250, srcComponent=190)
        self.enc1 = M1.MAVLink(None, srcSystem=250, srcComponent=190)
        self.foreign_sim = M.MAVLink(None, srcSystem=FOREIGN_SYSID, srcComponent=SIM_COMPONENT_ID)

    def pack(self, msg) -> bytes:
        return msg.pack(self.enc)

    def hostile(self) -> float:
        return self.rng.choice(HOSTILE_FLOATS)

    # classes common to both links
    def garbage(self) -> bytes:
        return self.rng.randbytes(self.rng.randint(1, 300))

    def truncated_v2(self, valid: bytes) -> bytes:
        return valid[: self.rng.randint(1, len(valid) - 1)]

    def truncated_v1(self) -> bytes:
        e = self.enc1
        v1 = e.command_long_encode(FC_SYSID, 1, M.MAV_CMD_NAV_LAND, 0, 0, 0, 0, 0, 0, 0, 0).pack(e)
        return v1[: self.rng.randint(1, len(v1) - 1)]

    def bad_crc(self, valid: bytes) -> bytes:
        b = bytearray(valid)
        b[-1] ^= self.rng.randint(1, 255)
        return bytes(b)

    # ground link: valid CRC, hostile content (must all be refused, today)
    def ground_hostile(self) -> tuple[str, bytes]:
        e, r, h = self.enc, self.rng, self.hostile
        kind = r.randrange(9)
        if kind == 0:
            return "setpoint_nan", self.pack(e.set_position_target_local_ned_encode(
                0, FC_SYSID, 1, M.MAV_FRAME_LOCAL_NED, 0xDF8, h(), h(), h(), 0, 0, 0, 0, 0, 0, h(), 0))  # fmt: skip
        if kind == 1:
            return "setpoint_nan", self.pack(e.set_position_target_global_int_encode(
                0, FC_SYSID, 1, M.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT, 0xDF8, r.choice((2**31 - 1, -(2**31))), 0, h(),
                0, 0, 0, 0, 0, 0, 0, 0))  # fmt: skip
        if kind == 2:
            cmd, params = r.choice((
                (M.MAV_CMD_COMPONENT_ARM_DISARM, (r.choice((NAN, INF, 1e30, 2.0, -1.0)), 0)),
                (M.MAV_CMD_NAV_TAKEOFF, (0, 0, 0, 0, 0, 0, h())),
                (M.MAV_CMD_DO_SET_MODE, (h(), h())),
                (M.MAV_CMD_DO_SET_MODE, (1, 1e30)),
                (M.MAV_CMD_SET_MESSAGE_INTERVAL, (M.MAVLINK_MSG_ID_HEARTBEAT, r.choice((1e30, INF, NAN, 5e6, -1)))),
                (M.MAV_CMD_SET_MESSAGE_INTERVAL, (r.choice((1e30, NAN, -5.0)), 1000)),
                (M.MAV_CMD_REQUEST_MESSAGE, (r.choice((NAN, INF, 1e30)),)),
                (M.MAV_CMD_DO_REPOSITION, (-1, 0, 0, h(), h(), h(), h())),
                (M.MAV_CMD_DO_SET_MISSION_CURRENT, (r.choice((NAN, 1e30, -7.0)),)),
                (M.MAV_CMD_INJECT_FAILURE, (h(), h(), h())),
                (M.MAV_CMD_MISSION_START, (h(), h())),
            ))  # fmt: skip
            p = list(params) + [0.0] * (7 - len(params))
            return "command_long_nan", self.pack(e.command_long_encode(FC_SYSID, 1, cmd, 0, *p))
        if kind == 3:
            cmd = r.choice((M.MAV_CMD_DO_REPOSITION, M.MAV_CMD_NAV_TAKEOFF, M.MAV_CMD_DO_SET_MODE))
            return "command_int_nan", self.pack(e.command_int_encode(
                FC_SYSID, 1, M.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT, cmd, 0, 0, h(), h(), h(), h(),
                r.choice((2**31 - 1, -(2**31))), r.choice((2**31 - 1, -(2**31))), h()))  # fmt: skip
        if kind == 4:
            names = (b"SMC_Z_KD", b"FS_GCS_ENABLE", b"RTL_ALT_M", b"SYSID_THISMAV", b"TELEM_RATE_HZ", b"SIM_WIND_SPD")
            name = r.choice(names) if r.random() < 0.5 else bytes(r.choice(b"ABCDEFGHIJKLMNOPQRSTUVWXYZ_") for _ in range(16))
            return "param_set_hostile", self.pack(e.param_set_encode(FC_SYSID, 1, name, r.choice(HOSTILE_FLOATS + HUGE), 9))
        if kind == 5:
            return "mission_count_range", self.pack(e.mission_count_encode(FC_SYSID, 1, r.choice((501, 65535, 10_000)), 0))
        if kind == 6:
            return "mission_item_seq", self.pack(e.mission_item_int_encode(
                FC_SYSID, 1, r.randint(3, 65535), M.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT, M.MAV_CMD_NAV_WAYPOINT, 0, 1,
                h(), h(), h(), h(), 2**31 - 1, -(2**31), h(), 0))  # fmt: skip
        if kind == 7:
            group = r.choice((M.MAV_DATA_STREAM_ALL, 7, 99, 200))
            # every group at 65535 Hz or off: accepted, bounded (MIN_INTERVAL_US); unknown groups refused
            cls = "request_data_stream_bounded" if group == M.MAV_DATA_STREAM_ALL else "request_data_stream_unknown"
            return cls, self.pack(e.request_data_stream_encode(FC_SYSID, 1, group, r.choice((65535, 0, 1000)), 1))
        return "setpoint_bad_frame", self.pack(e.set_position_target_local_ned_encode(
            0, FC_SYSID, 1, r.choice((M.MAV_FRAME_BODY_FRD, 99, M.MAV_FRAME_GLOBAL)), 0xDF8, 1, 1, -2, 0, 0, 0, 0, 0, 0, 0, 0))  # fmt: skip

    def ground_other_system(self) -> bytes:
        """Commands that would change the flight, for another vehicle: dropped."""
        e, r = self.enc, self.rng
        ts = r.choice((FOREIGN_SYSID, 2, 254))
        return self.pack(r.choice((
            e.command_long_encode(ts, 1, M.MAV_CMD_NAV_LAND, 0, 0, 0, 0, 0, 0, 0, 0),
            e.command_long_encode(ts, 1, M.MAV_CMD_COMPONENT_ARM_DISARM, 0, 0, 21196, 0, 0, 0, 0, 0),
            e.set_position_target_local_ned_encode(0, ts, 1, M.MAV_FRAME_LOCAL_NED, 0xDF8, 5, 5, -5, 0, 0, 0, 0, 0, 0, 0, 0),
            e.param_set_encode(ts, 1, b"SMC_Z_KD", 3.0, M.MAV_PARAM_TYPE_REAL32),
            e.set_mode_encode(ts, M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, 9),
        )))  # fmt: skip

    def valid_ground(self) -> bytes:
        e = self.enc
        return self.pack(e.command_long_encode(FOREIGN_SYSID, 1, M.MAV_CMD_NAV_LAND, 0, 0, 0, 0, 0, 0, 0, 0))

    def valid_sim_state(self, enc: M.MAVLink) -> bytes:
        return enc.attitude_encode(1000, 0.5, 0.5, 0.5, 0, 0, 0).pack(enc) + enc.local_position_ned_encode(1000, 9, 9, -9, 0, 0, 0).pack(enc)

    def datagram(self, target: str) -> bytes:
        """One hostile datagram for ``target`` ("gcs", "fc_sim", "sim"), counted by class."""
        r = self.rng
        if target == "gcs":
            kind = r.choices(("garbage", "truncated_v2", "truncated_v1", "bad_crc", "hostile", "other_system"),
                             (2, 1, 1, 1, 6, 2))[0]  # fmt: skip
            if kind == "hostile":
                cls, data = self.ground_hostile()
                self.sent[(target, cls)] += 1
                return data
            if kind == "other_system":
                data = self.ground_other_system()
            elif kind == "garbage":
                data = self.garbage()
            elif kind == "truncated_v1":
                data = self.truncated_v1()
            elif kind == "truncated_v2":
                data = self.truncated_v2(self.valid_ground())
            else:
                data = self.bad_crc(self.valid_ground())
            self.sent[(target, kind)] += 1
            return data
        kind = r.choice(("garbage", "truncated_v2", "truncated_v1", "bad_crc", "other_system"))
        enc = self.foreign_sim
        if kind == "garbage":
            data = self.garbage()
        elif kind == "truncated_v1":
            data = self.truncated_v1()
        elif kind == "other_system":
            if target == "fc_sim":
                data = self.valid_sim_state(enc)  # a state from another system id: dropped, counted
            else:
                data = enc.hil_actuator_controls_encode(1000, [1.0] * 16, 0, 0).pack(enc)
        else:
            valid = self.valid_sim_state(M.MAVLink(None, srcSystem=FC_SYSID, srcComponent=SIM_COMPONENT_ID))
            valid = valid[: 12 + valid[1]]  # the ATTITUDE alone
            data = self.truncated_v2(valid) if kind == "truncated_v2" else self.bad_crc(valid)
        self.sent[(target, kind)] += 1
        return data


# -- a flood at a fixed rate ---------------------------------------------------------------------
@dataclass(frozen=True)
class FloodSpec:
    """A ground-link flood: ``hostile`` datagrams spread evenly over ``seconds`` (three in five to
    the FC's ground port, one to its simulator port, one to the simulator's port), plus a
    heartbeat from each of ``systems`` ground-station systems (each on its own socket) at
    ``heartbeat_hz``."""

    hostile: int = 20_000
    seconds: float = 33.0
    systems: int = 50
    heartbeat_hz: float = 10.0
    seed: int = 20261203


def flood_datagrams(fuzzer: Fuzzer, n: int) -> list[tuple[str, bytes]]:
    """``n`` hostile datagrams and their targets ("gcs", "fc_sim", "sim"), built before the flood
    starts (so building them costs the measured machine nothing while the flight runs)."""
    order = ("gcs", "gcs", "gcs", "fc_sim", "sim")
    return [(order[i % len(order)], fuzzer.datagram(order[i % len(order)])) for i in range(n)]


def heartbeat_flood(systems: int) -> list[tuple[socket.socket, bytes]]:
    """One socket on 127.0.0.1 and one ground-station heartbeat (systems 100, 101, ...) per
    flooding system; the caller closes the sockets."""
    flood: list[tuple[socket.socket, bytes]] = []
    for i in range(systems):
        s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        flood.append((s, b""))
        s.bind((LOOPBACK, 0))
        enc = M.MAVLink(None, srcSystem=100 + i, srcComponent=190)
        flood[-1] = (s, enc.heartbeat_encode(M.MAV_TYPE_GCS, M.MAV_AUTOPILOT_INVALID, 0, 0, 4).pack(enc))
    return flood


def send_flood(
    targets: dict[str, tuple[str, int]], datagrams: Sequence[tuple[str, bytes]], spec: FloodSpec, stop: threading.Event,
    sent: Counter | None = None,
) -> None:  # fmt: skip
    """Send ``datagrams`` evenly over ``spec.seconds`` (absolute schedule: a late send does not
    shift the rest) and the heartbeat flood beside them, until done or ``stop``; counts in ``sent``
    by (target, class) as :class:`Fuzzer` does ("heartbeat_flood" for the heartbeats)."""
    sent = sent if sent is not None else Counter()
    flood = heartbeat_flood(spec.systems)
    try:
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as out:
            out.bind((LOOPBACK, 0))
            t0 = time.monotonic()
            step = spec.seconds / max(1, len(datagrams))
            hb_step = 1.0 / spec.heartbeat_hz
            i, n_hb = 0, 0
            end = t0 + spec.seconds
            while not stop.is_set():
                now = time.monotonic()
                if now >= end:
                    break
                while i < len(datagrams) and t0 + i * step <= now:
                    target, data = datagrams[i]
                    i += 1
                    with contextlib.suppress(OSError):
                        out.sendto(data, targets[target])
                if t0 + n_hb * hb_step <= now:
                    n_hb += 1
                    for s, hb in flood:
                        with contextlib.suppress(OSError):
                            s.sendto(hb, targets["gcs"])
                    sent[("gcs", "heartbeat_flood")] += len(flood)
                nxt = min(t0 + i * step if i < len(datagrams) else end, t0 + n_hb * hb_step, end)
                time.sleep(max(0.0, nxt - time.monotonic()))
            sent[("all", "hostile_sent")] += i
    finally:
        for s, _ in flood:
            s.close()


# -- a real-time flight with a commanding station ---------------------------------------------------
#: the station's commands: one every this many wall seconds, from COMMAND_START_S of the flight on.
COMMAND_PERIOD_S = 0.5
COMMAND_START_S = 6.0
#: a command unanswered this long (wall s) is counted unanswered and the next one is sent.
COMMAND_GIVE_UP_S = 5.0


@dataclass
class Flight:
    """One real-time flight's figures."""

    fc_summary: dict
    #: (time_boot_ms, north, east, down) of every simulator state the FC flew.
    track: list[tuple[int, float, float, float]]
    #: wall seconds from each command sent to its COMMAND_ACK.
    answers_s: list[float]
    unanswered: int
    sent: Counter = field(default_factory=Counter)

    @property
    def ticks(self) -> int:
        return int(self.fc_summary.get("ticks", 0))

    @property
    def overruns(self) -> int:
        return int(self.fc_summary.get("overruns", 0))

    @property
    def cpu_s(self) -> float:
        """The FC process's CPU seconds (user + system) over the run."""
        v = self.fc_summary.get("cpu_s")
        return math.nan if v is None else float(v)

    @property
    def p99_s(self) -> float:
        v = self.fc_summary.get("lateness_p99_s")
        return math.nan if v is None else float(v)


def read_track(tlog: Path) -> list[tuple[int, float, float, float]]:
    """The simulator's positions the FC flew, from its log: (time_boot_ms, north, east, down)."""
    from smcpilot.tlog import read_tlog

    out = []
    for _t, msg in read_tlog(tlog):
        if msg.get_msgId() == M.MAVLINK_MSG_ID_LOCAL_POSITION_NED and msg.get_srcComponent() == SIM_COMPONENT_ID:
            out.append((int(msg.time_boot_ms), float(msg.x), float(msg.y), float(msg.z)))
    return sorted(dict((r[0], r) for r in out).values())


def track_deviation(a: Sequence[tuple[int, float, float, float]], b: Sequence[tuple[int, float, float, float]]) -> tuple[float, float]:
    """(largest, RMS) distance in metres between two tracks at ``a``'s stamps within ``b``'s span
    (``b`` interpolated linearly between its stamps)."""
    stamps = [r[0] for r in b]
    worst, sq, n = 0.0, 0.0, 0
    for t, x, y, z in a:
        j = bisect.bisect_left(stamps, t)
        if j == 0 or j >= len(b):
            if j < len(b) and stamps[j] == t:
                bx, by, bz = b[j][1:]
            else:
                continue
        else:
            t0, x0, y0, z0 = b[j - 1]
            t1, x1, y1, z1 = b[j]
            w = (t - t0) / (t1 - t0)
            bx, by, bz = x0 + w * (x1 - x0), y0 + w * (y1 - y0), z0 + w * (z1 - z0)
        d = math.dist((x, y, z), (bx, by, bz))
        worst = max(worst, d)
        sq += d * d
        n += 1
    return worst, math.sqrt(sq / n) if n else math.nan


def _station_commands(conn: socket.socket, fc: tuple[str, int], enc: M.MAVLink, until: threading.Event,
                      answers: list[float], unanswered: list[int], started: float) -> None:  # fmt: skip
    """A well-behaved ground station: a heartbeat a second, and from COMMAND_START_S on one
    command at a time every COMMAND_PERIOD_S, alternately ARM (accepted: already armed) and
    DISARM without force (refused: flying), neither of which changes the flight; each answer's
    wall time is recorded."""
    dec = M.MAVLink(None)
    dec.robust_parsing = True
    next_hb = 0.0
    next_cmd = started + COMMAND_START_S
    pending: tuple[int, float] | None = None
    n = 0
    while not until.is_set():
        now = time.monotonic()
        if now >= next_hb:
            next_hb = now + 1.0
            conn.sendto(enc.heartbeat_encode(M.MAV_TYPE_GCS, M.MAV_AUTOPILOT_INVALID, 0, 0, M.MAV_STATE_ACTIVE).pack(enc), fc)
        if pending is None and now >= next_cmd:
            arm = n % 2 == 0
            n += 1
            cmd = enc.command_long_encode(FC_SYSID, 1, M.MAV_CMD_COMPONENT_ARM_DISARM, 0, 1.0 if arm else 0.0, 0, 0, 0, 0, 0, 0)
            conn.sendto(cmd.pack(enc), fc)
            pending = (M.MAV_CMD_COMPONENT_ARM_DISARM, time.monotonic())
            next_cmd = now + COMMAND_PERIOD_S
        if pending is not None and now - pending[1] > COMMAND_GIVE_UP_S:
            unanswered[0] += 1
            pending = None
        try:
            conn.settimeout(0.02)
            data = conn.recv(65535)
        except (TimeoutError, OSError):
            continue
        t_rx = time.monotonic()
        for m in dec.parse_buffer(data) or ():
            if pending is not None and m.get_type() == "COMMAND_ACK" and m.command == pending[0] and m.target_system == enc.srcSystem:
                answers.append(t_rx - pending[1])
                pending = None


def fly_realtime(workdir: Path, name: str, *, duration_s: float, plan: Path, flood: FloodSpec | None,
                 datagrams: Sequence[tuple[str, bytes]] = ()) -> Flight:  # fmt: skip
    """One real-time SITL flight (500 Hz, the FC's ground link to a listener), with the commanding
    station, and the flood from ``COMMAND_START_S - 3`` wall seconds after the FC is ready."""
    from ground.sitl import Sitl, SitlOptions

    run_dir = workdir / name
    run_dir.mkdir(parents=True)
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as listener:
        listener.bind((LOOPBACK, 0))
        opts = SitlOptions.of(lockstep=False, duration_s=duration_s, plan=plan, gcs=f"udp:{LOOPBACK}:{listener.getsockname()[1]}",
                              tlog=run_dir / "fc.tlog", param_file=run_dir / "fc.parm", log_dir=run_dir, watchdog_s=10.0)  # fmt: skip
        stop = threading.Event()
        sent: Counter = Counter()
        answers: list[float] = []
        unanswered = [0]
        with Sitl(opts, echo=lambda line: None) as sitl, socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as conn:
            started = time.monotonic()
            assert sitl.gcs_address is not None and sitl.sim is not None
            host, port = sitl.gcs_address.rsplit(":", 1)
            fc_gcs = (host, int(port))
            assert sitl.sim_port is not None
            conn.bind((LOOPBACK, 0))
            enc = M.MAVLink(None, srcSystem=255, srcComponent=190)
            station = threading.Thread(target=_station_commands, args=(conn, fc_gcs, enc, stop, answers, unanswered, started), daemon=True)
            station.start()
            flooder = None
            if flood is not None:
                sim_ports = udp_ports(sitl.sim.proc.pid)
                targets = {"gcs": fc_gcs, "fc_sim": (LOOPBACK, sitl.sim_port), "sim": (LOOPBACK, sim_ports[0])}
                flood_stop = threading.Event()

                def run_flood() -> None:
                    if not stop.wait(max(0.0, started + COMMAND_START_S - 3.0 - time.monotonic())):
                        send_flood(targets, datagrams, flood, flood_stop if not stop.is_set() else stop, sent)

                flooder = threading.Thread(target=run_flood, daemon=True)
                flooder.start()
            try:
                sitl.wait(timeout_s=duration_s + 120)
            finally:
                stop.set()
                station.join(5)
                if flooder is not None:
                    flooder.join(5)
            summary = sitl.fc_summary or {}
    return Flight(summary, read_track(opts.tlog), answers, unanswered[0], sent)  # type: ignore[arg-type]


# -- smcpilot bench flood --------------------------------------------------------------------------
def add_arguments(sub: argparse._SubParsersAction) -> None:
    c = sub.add_parser("flood", help="real time under a ground-link flood vs clean, back to back: overruns, lateness, track, command answers")
    c.add_argument("--pairs", type=int, default=2, help="clean + flooded pairs, back to back (default 2)")
    c.add_argument("--duration", type=float, default=40.0, metavar="S", help="flight length, wall = simulated seconds (default 40)")
    c.add_argument("--hostile", type=int, default=FloodSpec.hostile, help=f"hostile datagrams per flood (default {FloodSpec.hostile})")
    c.add_argument("--flood-s", type=float, default=FloodSpec.seconds, metavar="S", help=f"flood length, wall seconds (default {FloodSpec.seconds:g})")
    c.add_argument("--systems", type=int, default=FloodSpec.systems, help=f"heartbeat-flood systems at 10 Hz each (default {FloodSpec.systems})")
    c.add_argument("--seed", type=int, default=FloodSpec.seed, help="the hostile datagrams' seed")
    c.add_argument("--burn", type=int, default=0, metavar="N",
                   help="N busy processes during every run, clean and flooded (a loaded machine; default 0)")
    c.set_defaults(bench=bench_flood)


@contextlib.contextmanager
def burning(n: int) -> Iterator[None]:
    """``n`` busy Python processes while the block runs (stopped, by their ids, after it)."""
    procs = [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(n)]
    try:
        yield
    finally:
        for p in procs:
            p.kill()
            p.wait()


def _pct(xs: Sequence[float], p: float) -> float:
    s = sorted(xs)
    return s[min(len(s) - 1, int(p * (len(s) - 1) + 0.5))] if s else math.nan


def _ratio(a: float, b: float) -> str:
    if b == 0:
        return "—" if a == 0 else "∞×"
    return f"{a / b:.2f}×"


def _line(label: str, f: Flight) -> str:
    ans = f.answers_s
    return (f"  {label:<6} {f.ticks:6d} ticks, {f.overruns:5d} overruns ({100.0 * f.overruns / max(1, f.ticks + f.overruns):.2f} %),"
            f" lateness p99 {f.p99_s * 1e6:6.0f} µs, FC CPU {f.cpu_s:5.2f} s, commands answered {len(ans)} (unanswered {f.unanswered}),"
            f" answer p50/max {_pct(ans, 0.5) * 1e3:.1f}/{max(ans, default=math.nan) * 1e3:.1f} ms")  # fmt: skip


def _budget_line(b: dict | None) -> str:
    """The FC's ground-link budget figures (its exit summary's ``gcs_budget``), in one line."""
    if not b:
        return "ground-link budget: n/a (an FC without one)"
    dropped = ", ".join(f"{name} {v['dropped']}" for name, v in b.get("by_class", {}).items() if v.get("dropped"))
    return (f"ground link: {b.get('handled')} datagrams handled, {b.get('deferred')} of them in a later period"
            f" (at most {b.get('max_wait_periods')} periods), {b.get('dropped')} dropped{f' ({dropped})' if dropped else ''},"
            f" budget spent in {b.get('periods_out_of_budget')} periods, {b.get('work_s')} s of ground work,"
            f" telemetry messages deferred {b.get('telemetry_deferred')}, batches not sent to strangers"
            f" {b.get('telemetry_peers_skipped')}")  # fmt: skip


def bench_flood(args: argparse.Namespace) -> int:
    from ground.sitl_cmd import demo_plan_path
    from smcpilot.errors import ConfigError

    if args.burn < 0:
        raise ConfigError("--burn must be >= 0")
    if args.pairs < 1 or not args.duration > 0 or args.hostile < 0 or not args.flood_s > 0 or args.systems < 0:
        raise ConfigError("--pairs must be >= 1, --duration and --flood-s > 0, --hostile and --systems >= 0")
    if args.flood_s + COMMAND_START_S - 3.0 > args.duration:
        raise ConfigError(f"--flood-s must end before the flight does: at most {args.duration - COMMAND_START_S + 3.0:g} s")
    spec = FloodSpec(hostile=args.hostile, seconds=args.flood_s, systems=args.systems, seed=args.seed)
    plan = demo_plan_path()
    load = os.getloadavg()
    print(f"smcpilot bench flood — Python {platform.python_version()}, real time at 500 Hz, {args.duration:g} s of the demo"
          f" plan; flood: {spec.hostile} hostile datagrams over {spec.seconds:g} s + heartbeats from {spec.systems} systems"
          f" at {spec.heartbeat_hz:g} Hz; a station commands every {COMMAND_PERIOD_S:g} s; {args.pairs} pair(s), clean then"
          f" flooded; load {load[0]:.2f} on {os.cpu_count()} cores" + (f"; {args.burn} busy processes beside each run" if args.burn else ""))  # fmt: skip
    datagrams = flood_datagrams(Fuzzer(spec.seed), spec.hostile)
    cleans: list[Flight] = []
    rows: list[tuple[float, float, float, float]] = []
    with tempfile.TemporaryDirectory(prefix="bench-flood-") as tmp:
        for k in range(args.pairs):
            with burning(args.burn):
                clean = fly_realtime(Path(tmp), f"clean{k}", duration_s=args.duration, plan=plan, flood=None)
            with burning(args.burn):
                flooded = fly_realtime(Path(tmp), f"flood{k}", duration_s=args.duration, plan=plan, flood=spec, datagrams=datagrams)
            dev, rms = track_deviation(flooded.track, clean.track)
            print(f"\npair {k + 1} (load {os.getloadavg()[0]:.2f}):")
            print(_line("clean", clean))
            print(_line("flood", flooded))
            fs = flooded.fc_summary
            print(f"  flood sent {flooded.sent[('all', 'hostile_sent')]} hostile + {flooded.sent[('gcs', 'heartbeat_flood')]} heartbeats;"
                  f" FC rejected {fs.get('rx_rejected', {}).get('total')}; the kernel dropped"
                  f" {((fs.get('links') or {}).get('gcs') or {}).get('kernel_drops', 'n/a')} (socket buffer full);"
                  f" {_budget_line(fs.get('gcs_budget'))}")  # fmt: skip
            worst_ans = max(flooded.answers_s, default=math.inf)
            print(f"  ratios flood/clean: overruns {_ratio(flooded.overruns, clean.overruns)} (goal ≤ 2×),"
                  f" p99 lateness {_ratio(flooded.p99_s, clean.p99_s)}, FC CPU {_ratio(flooded.cpu_s, clean.cpu_s)}; track deviation max {dev * 100:.2f} cm"
                  f" (RMS {rms * 100:.2f} cm; goal ≤ 2 cm); slowest command answer {worst_ans * 1e3:.0f} ms (goal ≤ 1000 ms)")  # fmt: skip
            if cleans:
                floor, floor_rms = track_deviation(clean.track, cleans[0].track)
                print(f"  noise floor: this clean run vs pair 1's clean run: max {floor * 100:.2f} cm (RMS {floor_rms * 100:.2f} cm)")
            cleans.append(clean)
            rows.append((flooded.overruns / max(1, clean.overruns), flooded.p99_s / clean.p99_s if clean.p99_s else math.nan, dev, worst_ans))
    if len(rows) > 1:
        worst = [max(r[i] for r in rows) for i in range(4)]
        print(f"\nworst of {len(rows)} pairs: overruns {worst[0]:.2f}× (clean 0 counted as 1), p99 lateness {worst[1]:.2f}×,"
              f" track deviation {worst[2] * 100:.2f} cm, slowest command answer {worst[3] * 1e3:.0f} ms")  # fmt: skip
    print("goals: overruns ≤ 2× the clean run's, track deviation ≤ 2 cm, commands answered within 1 s")
    return 0
