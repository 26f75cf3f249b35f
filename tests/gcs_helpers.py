"""A ground station built from raw pymavlink, for testing the FC's ground protocol from outside.

Nothing here uses the project's own client (``ground/client.py``) or the FC's code: the tests talk
to the real FC process over UDP the way MAVProxy, QGroundControl or MAVSDK would.

- :class:`Gcs` wraps a ``mavutil`` UDP connection: it keeps every message received (with the
  wall time it arrived), follows the FC's simulated clock (``time_boot_ms`` of its telemetry),
  sends GCS heartbeats at 1 Hz (wall) like every ground station, and offers waits, commands with
  acks, parameter reads/sets and the mission protocol.
- :func:`sitl_run` starts lockstep SITL (:class:`ground.sitl.Sitl`) with the FC's ground link
  pointing at a :class:`Gcs` on a free port.
- :class:`LossyProxy` is a UDP relay that drops a share of datagrams each way (seeded, so the
  drop pattern is deterministic).
- Flat-earth helpers convert metres north/east of home to latitude/longitude and back.

Wall-clock limits are generous (only to turn hangs into failures); flight waits are bounded in
simulated seconds.
"""

from __future__ import annotations

import contextlib
import hashlib
import math
import random
import select
import socket
import threading
import time
from collections import deque
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path

from pymavlink import mavutil
from pymavlink.dialects.v20 import ardupilotmega as M

from ground.sitl import Sitl, SitlOptions

LOOPBACK = "127.0.0.1"
GCS_SYSID = 255
GCS_COMPID = 190  # MAV_COMP_ID_MISSIONPLANNER
FC_SYSID = 1
FC_COMPID = 1
#: Wall-clock limit for anything that should take a fraction of a second (hang guard only).
WALL_S = 30.0

#: ArduPilot's SITL field, the FC's default home.
HOME_LAT = -35.363261
HOME_LON = 149.165230
HOME_ALT = 584.0
EARTH_RADIUS_M = 6378137.0


# -- geometry ------------------------------------------------------------------------------------
def ne_to_latlon(north_m: float, east_m: float, lat0: float = HOME_LAT, lon0: float = HOME_LON) -> tuple[float, float]:
    lat = lat0 + math.degrees(north_m / EARTH_RADIUS_M)
    lon = lon0 + math.degrees(east_m / (EARTH_RADIUS_M * math.cos(math.radians(lat0))))
    return lat, lon


def latlon_to_ne(lat: float, lon: float, lat0: float = HOME_LAT, lon0: float = HOME_LON) -> tuple[float, float]:
    north = math.radians(lat - lat0) * EARTH_RADIUS_M
    east = math.radians(lon - lon0) * EARTH_RADIUS_M * math.cos(math.radians(lat0))
    return north, east


def gpi_ne(m) -> tuple[float, float]:
    """(north, east) m of home of a GLOBAL_POSITION_INT."""
    return latlon_to_ne(m.lat * 1e-7, m.lon * 1e-7)


# -- the ground station --------------------------------------------------------------------------
@dataclass
class Rx:
    msg: object
    wall: float
    sim_ms: int


class Gcs:
    """One ground station on one UDP socket (``udpin:HOST:PORT`` listens, ``udpout:HOST:PORT`` sends)."""

    def __init__(self, url: str = f"udpin:{LOOPBACK}:0", *, sysid: int = GCS_SYSID, compid: int = GCS_COMPID,
                 heartbeats: bool = True) -> None:  # fmt: skip
        self.conn = mavutil.mavlink_connection(url, source_system=sysid, source_component=compid, dialect="ardupilotmega")
        with contextlib.suppress(OSError):
            self.conn.port.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 1 << 22)
        self.sysid = sysid
        self.compid = compid
        self.heartbeats = heartbeats
        self.heartbeat_period_s = 1.0
        self._next_hb = 0.0
        self.log: list[Rx] = []
        self.sim_ms = -1
        self.last: dict[str, object] = {}
        #: PARAM_REQUEST_READs sent by :meth:`param_list` for lost values
        self.param_rerequests = 0

    # plumbing ----------------------------------------------------------------------------------
    @property
    def port(self) -> int:
        return self.conn.port.getsockname()[1]

    @property
    def mav(self):
        return self.conn.mav

    def close(self) -> None:
        self.conn.close()

    def send_heartbeat(self) -> None:
        self.mav.heartbeat_send(M.MAV_TYPE_GCS, M.MAV_AUTOPILOT_INVALID, 0, 0, M.MAV_STATE_ACTIVE)

    def pump(self, timeout: float = 0.02) -> int:
        """Send a heartbeat if one is due, wait up to ``timeout`` for data, take everything queued."""
        now = time.monotonic()
        if self.heartbeats and now >= self._next_hb:
            self._next_hb = now + self.heartbeat_period_s
            self.send_heartbeat()
        n = 0
        r, _, _ = select.select([self.conn.port], [], [], timeout)
        if not r:
            return 0
        while True:
            m = self.conn.recv_msg()
            if m is None:
                break
            if m.get_type() == "BAD_DATA":
                continue
            t = getattr(m, "time_boot_ms", None)
            if t is not None and m.get_srcSystem() == FC_SYSID and m.get_type() != "NAMED_VALUE_INT":
                self.sim_ms = max(self.sim_ms, t)
            self.log.append(Rx(m, time.monotonic(), self.sim_ms))
            self.last[m.get_type()] = m
            n += 1
            if n > 5000:
                break
        return n

    def mark(self) -> int:
        """A position in the log: :meth:`since` and ``wait(since=...)`` look only after it."""
        return len(self.log)

    def since(self, mark: int, type: str | Sequence[str] | None = None, pred: Callable | None = None) -> list:
        types = {type} if isinstance(type, str) else set(type) if type is not None else None
        return [r.msg for r in self.log[mark:] if (types is None or r.msg.get_type() in types) and (pred is None or pred(r.msg))]

    def texts(self, mark: int = 0) -> list[str]:
        return [m.text for m in self.since(mark, "STATUSTEXT")]

    def wait(self, type: str | Sequence[str] | None, pred: Callable | None = None, *, since: int | None = None,
             timeout: float = WALL_S, sim_timeout_s: float | None = None, what: str = "") -> object:  # fmt: skip
        """The first message of ``type`` matching ``pred`` after ``since`` (default: now).
        Fails after ``timeout`` wall seconds or ``sim_timeout_s`` simulated seconds."""
        types = {type} if isinstance(type, str) else set(type) if type is not None else None
        start = self.mark() if since is None else since
        i = start
        deadline = time.monotonic() + timeout
        sim0 = self.sim_ms
        while True:
            while i < len(self.log):
                m = self.log[i].msg
                i += 1
                if (types is None or m.get_type() in types) and (pred is None or pred(m)):
                    return m
            now = time.monotonic()
            if now > deadline or (sim_timeout_s is not None and sim0 >= 0 and self.sim_ms - sim0 > sim_timeout_s * 1000):
                last = self.last.get(next(iter(types))) if types else None
                raise AssertionError(
                    f"no {what or types} within {timeout:g} wall s"
                    + (f" / {sim_timeout_s:g} sim s" if sim_timeout_s is not None else "")
                    + f"; last of that type: {last}; recent STATUSTEXT: {self.texts(start)[-5:]}"
                )
            self.pump(0.02)

    def until(self, cond: Callable[[], bool], *, sim_timeout_s: float, timeout: float = 120.0, what: str = "") -> None:
        """Pump until ``cond()`` holds; fail after ``sim_timeout_s`` simulated (or ``timeout`` wall) seconds."""
        self.pump(0.0)
        sim0 = self.sim_ms
        deadline = time.monotonic() + timeout
        while not cond():
            if time.monotonic() > deadline or (sim0 >= 0 and self.sim_ms - sim0 > sim_timeout_s * 1000):
                raise AssertionError(
                    f"condition not met within {sim_timeout_s:g} sim s ({what}); last GLOBAL_POSITION_INT:"
                    f" {self.last.get('GLOBAL_POSITION_INT')}; last HEARTBEAT: {self.last.get('HEARTBEAT')};"
                    f" STATUSTEXT: {self.texts()[-6:]}"
                )
            self.pump(0.02)

    def run_sim(self, seconds: float, timeout: float = 120.0) -> None:
        """Keep pumping while ``seconds`` of simulated time pass."""
        self.pump(0.0)
        while self.sim_ms < 0:
            self.pump(0.05)
        target = self.sim_ms + seconds * 1000
        self.until(lambda: self.sim_ms >= target, sim_timeout_s=seconds + 1, timeout=timeout, what=f"{seconds} sim s")

    def run_wall(self, seconds: float) -> None:
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            self.pump(min(0.05, max(0.0, end - time.monotonic())))

    # state ---------------------------------------------------------------------------------
    def heartbeat(self, since: int | None = None):
        """The next HEARTBEAT from the FC (after ``since``, default now)."""
        return self.wait("HEARTBEAT", lambda m: m.get_srcSystem() == FC_SYSID and m.get_srcComponent() == FC_COMPID,
                         since=since, what="FC HEARTBEAT")  # fmt: skip

    def armed(self) -> bool:
        hb = self.last.get("HEARTBEAT")
        return bool(hb and hb.base_mode & M.MAV_MODE_FLAG_SAFETY_ARMED)

    def mode(self) -> int | None:
        hb = self.last.get("HEARTBEAT")
        return hb.custom_mode if hb else None

    def rel_alt(self) -> float:
        m = self.last.get("GLOBAL_POSITION_INT")
        return m.relative_alt * 1e-3 if m is not None else math.nan

    def ne(self) -> tuple[float, float]:
        m = self.last.get("GLOBAL_POSITION_INT")
        return gpi_ne(m) if m is not None else (math.nan, math.nan)

    def landed_state(self) -> int | None:
        m = self.last.get("EXTENDED_SYS_STATE")
        return m.landed_state if m is not None else None

    # commands --------------------------------------------------------------------------------
    def send_command(self, cmd: int, *params: float, target: tuple[int, int] = (FC_SYSID, FC_COMPID),
                     confirmation: int = 0) -> int:  # fmt: skip
        p = list(params) + [0.0] * (7 - len(params))
        mark = self.mark()
        self.mav.command_long_send(target[0], target[1], cmd, confirmation, *p)
        return mark

    def ack(self, cmd: int, since: int, timeout: float = WALL_S):
        return self.wait("COMMAND_ACK", lambda m: m.command == cmd, since=since, timeout=timeout, what=f"COMMAND_ACK for {cmd}")

    def command(self, cmd: int, *params: float, expect: int | None = M.MAV_RESULT_ACCEPTED, **kw):
        """COMMAND_LONG; returns its COMMAND_ACK (checked: result ``expect``, addressed to us)."""
        mark = self.send_command(cmd, *params, **kw)
        ack = self.ack(cmd, mark)
        self.check_ack(ack, expect)
        return ack

    def command_int(self, cmd: int, frame: int, params: Sequence[float] = (), x: int = 0, y: int = 0, z: float = 0.0,
                    expect: int | None = M.MAV_RESULT_ACCEPTED, target: tuple[int, int] = (FC_SYSID, FC_COMPID)):  # fmt: skip
        p = list(params) + [0.0] * (4 - len(params))
        mark = self.mark()
        self.mav.command_int_send(target[0], target[1], frame, cmd, 0, 0, *p, x, y, z)
        ack = self.ack(cmd, mark)
        self.check_ack(ack, expect)
        return ack

    def check_ack(self, ack, expect: int | None) -> None:
        assert ack.target_system == self.sysid and ack.target_component == self.compid, (
            f"COMMAND_ACK not addressed to the sender ({self.sysid}/{self.compid}): {ack}"
        )
        if expect is not None:
            assert ack.result == expect, (
                f"command {ack.command}: result {ack.result}, expected {expect}; STATUSTEXT {self.texts()[-4:]}"
            )

    def set_mode(self, number: int, base_mode: int = M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, expect=M.MAV_RESULT_ACCEPTED):
        return self.command(M.MAV_CMD_DO_SET_MODE, base_mode, number, expect=expect)

    def wait_mode(self, number: int, sim_timeout_s: float = 5.0):
        return self.wait("HEARTBEAT", lambda m: m.get_srcSystem() == FC_SYSID and m.custom_mode == number,
                         sim_timeout_s=sim_timeout_s, what=f"HEARTBEAT with custom_mode {number}")  # fmt: skip

    def arm(self, expect=M.MAV_RESULT_ACCEPTED):
        return self.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1, expect=expect)

    def takeoff(self, alt_m: float, expect=M.MAV_RESULT_ACCEPTED):
        return self.command(M.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, math.nan, math.nan, math.nan, alt_m, expect=expect)

    def wait_altitude(self, alt_m: float, tol_m: float = 0.15, sim_timeout_s: float = 20.0, settle_s: float = 1.0) -> None:
        """Wait until the relative altitude is within ``tol_m`` of ``alt_m`` for ``settle_s`` sim s."""
        state = {"since": None}

        def ok() -> bool:
            if abs(self.rel_alt() - alt_m) <= tol_m:
                if state["since"] is None:
                    state["since"] = self.sim_ms
                return self.sim_ms - state["since"] >= settle_s * 1000
            state["since"] = None
            return False

        self.until(ok, sim_timeout_s=sim_timeout_s, what=f"altitude {alt_m} ± {tol_m} m")

    def take_off(self, alt_m: float = 3.0) -> None:
        """GUIDED, arm, take off, wait until settled at ``alt_m``."""
        if self.mode() != M.COPTER_MODE_GUIDED:
            self.set_mode(M.COPTER_MODE_GUIDED)
        self.arm()
        self.takeoff(alt_m)
        self.wait_altitude(alt_m)

    def wait_disarmed(self, sim_timeout_s: float = 30.0):
        return self.wait("HEARTBEAT", lambda m: m.get_srcSystem() == FC_SYSID and not m.base_mode & M.MAV_MODE_FLAG_SAFETY_ARMED,
                         sim_timeout_s=sim_timeout_s, what="disarmed HEARTBEAT")  # fmt: skip

    # parameters ------------------------------------------------------------------------------
    def param_read(self, name: str | None = None, index: int = -1):
        mark = self.mark()
        self.mav.param_request_read_send(FC_SYSID, FC_COMPID, (name or "").encode(), index)
        if name is not None and index < 0:
            return self.wait("PARAM_VALUE", lambda m: m.param_id == name, since=mark, what=f"PARAM_VALUE {name}")
        return self.wait("PARAM_VALUE", lambda m: m.param_index == index, since=mark, what=f"PARAM_VALUE #{index}")

    def param_set(self, name: str, value: float, ptype: int = M.MAV_PARAM_TYPE_REAL32):
        mark = self.mark()
        self.mav.param_set_send(FC_SYSID, FC_COMPID, name.encode(), value, ptype)
        return self.wait("PARAM_VALUE", lambda m: m.param_id == name, since=mark, what=f"PARAM_VALUE {name} after PARAM_SET")

    def param_list(self, *, rerequest: bool = False, timeout: float = 60.0) -> dict[int, object]:
        """PARAM_REQUEST_LIST; with ``rerequest``, ask for missing indices one by one (as GCSs do)."""
        mark = self.mark()
        self.mav.param_request_list_send(FC_SYSID, FC_COMPID)
        got: dict[int, object] = {}
        count = None
        seen = mark
        deadline = time.monotonic() + timeout
        quiet_since = time.monotonic()
        while time.monotonic() < deadline:
            self.pump(0.05)
            new = self.since(seen, "PARAM_VALUE")
            seen = self.mark()
            if new:
                quiet_since = time.monotonic()
            for m in new:
                count = m.param_count
                got.setdefault(m.param_index, m)
            if count is not None and len(got) >= count:
                return got
            if time.monotonic() - quiet_since > 0.5:
                if not rerequest:
                    return got
                if count is None:
                    self.mav.param_request_list_send(FC_SYSID, FC_COMPID)
                else:
                    for i in range(count):
                        if i not in got:
                            self.mav.param_request_read_send(FC_SYSID, FC_COMPID, b"", i)
                            self.param_rerequests += 1
                quiet_since = time.monotonic()
        return got


# -- missions ----------------------------------------------------------------------------------
#: MISSION_ITEM (float) frames of the MISSION_ITEM_INT frames
FLOAT_FRAME = {M.MAV_FRAME_GLOBAL_INT: M.MAV_FRAME_GLOBAL, M.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT: M.MAV_FRAME_GLOBAL_RELATIVE_ALT}


@dataclass(frozen=True)
class Item:
    """One mission item as MISSION_ITEM_INT carries it."""

    command: int
    frame: int = M.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT
    x: int = 0
    y: int = 0
    z: float = 0.0
    params: tuple[float, float, float, float] = (0.0, 0.0, 0.0, 0.0)
    autocontinue: int = 1

    def send(self, gcs: Gcs, seq: int, *, as_float: bool = False) -> None:
        p = self.params
        if as_float:
            frame = FLOAT_FRAME.get(self.frame, self.frame)
            x = self.x if isinstance(self.x, float) else self.x * 1e-7
            y = self.y if isinstance(self.y, float) else self.y * 1e-7
            gcs.mav.mission_item_send(FC_SYSID, FC_COMPID, seq, frame, self.command, 0, self.autocontinue, *p, x, y, self.z,
                                      M.MAV_MISSION_TYPE_MISSION)  # fmt: skip
        else:
            gcs.mav.mission_item_int_send(FC_SYSID, FC_COMPID, seq, self.frame, self.command, 0, self.autocontinue, *p,
                                          self.x, self.y, self.z, M.MAV_MISSION_TYPE_MISSION)  # fmt: skip


def waypoint(north_m: float, east_m: float, alt_m: float, command: int = M.MAV_CMD_NAV_WAYPOINT,
             frame: int = M.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT, params=(0.0, 0.0, 0.0, math.nan)) -> Item:  # fmt: skip
    lat, lon = ne_to_latlon(north_m, east_m)
    return Item(command, frame, round(lat * 1e7), round(lon * 1e7), alt_m, tuple(params))


def standard_mission(north1: float = 4.0, east2: float = 4.0) -> list[Item]:
    """home, take-off to 3 m, two waypoints, land at the last one."""
    home_lat, home_lon = round(HOME_LAT * 1e7), round(HOME_LON * 1e7)
    return [
        Item(M.MAV_CMD_NAV_WAYPOINT, M.MAV_FRAME_GLOBAL_INT, home_lat, home_lon, HOME_ALT),
        Item(M.MAV_CMD_NAV_TAKEOFF, M.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT, 0, 0, 3.0),
        waypoint(north1, 0.0, 3.0),
        waypoint(north1, east2, 4.0),
        waypoint(north1, east2, 0.0, command=M.MAV_CMD_NAV_LAND, params=(0.0, 0.0, 0.0, math.nan)),
    ]


def upload_mission(gcs: Gcs, items: Sequence[Item], *, as_float: bool = False, timeout: float = WALL_S,
                   resend_count_after_s: float | None = None) -> object:  # fmt: skip
    """MISSION_COUNT, answer every MISSION_REQUEST(_INT) for its seq, return the final MISSION_ACK.
    With ``resend_count_after_s``, resend MISSION_COUNT when nothing comes back for that long (a GCS
    retry); the upload is then restarted by the FC."""
    mark = gcs.mark()
    gcs.mav.mission_count_send(FC_SYSID, FC_COMPID, len(items), M.MAV_MISSION_TYPE_MISSION)
    seen = mark
    deadline = time.monotonic() + timeout
    last_rx = time.monotonic()
    while time.monotonic() < deadline:
        gcs.pump(0.02)
        for m in gcs.since(seen, ("MISSION_REQUEST_INT", "MISSION_REQUEST", "MISSION_ACK")):
            last_rx = time.monotonic()
            if m.get_type() == "MISSION_ACK":
                return m
            assert m.target_system == gcs.sysid, f"mission request not addressed to us: {m}"
            if 0 <= m.seq < len(items):
                items[m.seq].send(gcs, m.seq, as_float=as_float)
        seen = gcs.mark()
        if resend_count_after_s is not None and time.monotonic() - last_rx > resend_count_after_s:
            gcs.mav.mission_count_send(FC_SYSID, FC_COMPID, len(items), M.MAV_MISSION_TYPE_MISSION)
            last_rx = time.monotonic()
    raise AssertionError(f"mission upload did not finish within {timeout} s; STATUSTEXT {gcs.texts(mark)[-4:]}")


def download_mission(gcs: Gcs, *, retry_s: float | None = None, timeout: float = WALL_S) -> list:
    """MISSION_REQUEST_LIST -> MISSION_COUNT -> MISSION_REQUEST_INT each -> MISSION_ACK; the items.
    With ``retry_s``, repeat a request that got no answer (lossy links)."""
    deadline = time.monotonic() + timeout
    while True:
        mark = gcs.mark()
        gcs.mav.mission_request_list_send(FC_SYSID, FC_COMPID, M.MAV_MISSION_TYPE_MISSION)
        try:
            count = gcs.wait("MISSION_COUNT", since=mark, timeout=retry_s or WALL_S).count
            break
        except AssertionError:
            if retry_s is None or time.monotonic() > deadline:
                raise
    items = []
    for seq in range(count):
        while True:
            mark = gcs.mark()
            gcs.mav.mission_request_int_send(FC_SYSID, FC_COMPID, seq, M.MAV_MISSION_TYPE_MISSION)
            try:
                items.append(gcs.wait("MISSION_ITEM_INT", lambda m, s=seq: m.seq == s, since=mark, timeout=retry_s or WALL_S))
                break
            except AssertionError:
                if retry_s is None or time.monotonic() > deadline:
                    raise
    gcs.mav.mission_ack_send(FC_SYSID, FC_COMPID, M.MAV_MISSION_ACCEPTED, M.MAV_MISSION_TYPE_MISSION)
    return items


def same_item(got, want: Item, seq: int) -> list[str]:
    """Differences between a downloaded MISSION_ITEM_INT and what was uploaded."""
    diffs = []

    def eq(a: float, b: float) -> bool:
        return (math.isnan(a) and math.isnan(b)) or a == b

    for name, a, b in (("seq", got.seq, seq), ("frame", got.frame, want.frame), ("command", got.command, want.command),
                       ("x", got.x, want.x), ("y", got.y, want.y), ("autocontinue", got.autocontinue, want.autocontinue)):  # fmt: skip
        if a != b:
            diffs.append(f"item {seq} {name}: {a} != {b}")
    for name, a, b in (("z", got.z, want.z), ("param1", got.param1, want.params[0]), ("param2", got.param2, want.params[1]),
                       ("param3", got.param3, want.params[2]), ("param4", got.param4, want.params[3])):  # fmt: skip
        if not eq(a, b) and not (math.isfinite(a) and math.isfinite(b) and abs(a - b) <= 1e-6 * max(1.0, abs(b))):
            diffs.append(f"item {seq} {name}: {a} != {b}")
    return diffs


# -- SITL -----------------------------------------------------------------------------------------
@dataclass
class SitlRun:
    sitl: Sitl
    gcs: Gcs
    param_file: Path
    output: deque = field(default_factory=lambda: deque(maxlen=60))

    @property
    def fc_address(self) -> tuple[str, int]:
        host, port = self.sitl.gcs_address.rsplit(":", 1)
        return host, int(port)

    def tail(self) -> str:
        return "\n".join(self.output)


def write_params(path: Path, values: dict[str, float]) -> None:
    path.write_text("".join(f"{k} {v}\n" for k, v in values.items()), encoding="utf-8")


@contextlib.contextmanager
def sitl_run(tmp_path: Path, name: str = "fc", *, speed: float | None = 5.0, params: dict[str, float] | None = None,
             param_file: Path | None = None, gcs: Gcs | None = None, gcs_port: int | None = None) -> Iterator[SitlRun]:  # fmt: skip
    """Lockstep SITL whose FC sends its ground telemetry to ``gcs`` (a new :class:`Gcs` by default),
    or to ``gcs_port`` (e.g. a proxy) when given."""
    own_gcs = gcs is None and gcs_port is None
    if own_gcs:
        gcs = Gcs()
    param_file = param_file if param_file is not None else tmp_path / f"{name}.parm"
    if params:
        write_params(param_file, params)
    port = gcs_port if gcs_port is not None else gcs.port
    opts = SitlOptions.of(lockstep=True, speed=speed, gcs=f"udp:{LOOPBACK}:{port}", tlog=tmp_path / f"{name}.tlog",
                       param_file=param_file, log_dir=tmp_path, watchdog_s=10.0)  # fmt: skip
    out: deque = deque(maxlen=60)
    try:
        with Sitl(opts, echo=out.append) as sitl:
            run = SitlRun(sitl, gcs, param_file, out)  # type: ignore[arg-type]
            if gcs is not None and gcs_port is None:
                gcs.heartbeat()
            yield run
    finally:
        if own_gcs and gcs is not None:
            gcs.close()


# -- a lossy link ------------------------------------------------------------------------------
#: Messages of the request/answer protocols (everything else is streamed telemetry or heartbeats).
PROTOCOL_MSGS = frozenset(
    getattr(M, f"MAVLINK_MSG_ID_{n}")
    for n in ("COMMAND_LONG", "COMMAND_INT", "COMMAND_ACK", "PARAM_REQUEST_LIST", "PARAM_REQUEST_READ", "PARAM_SET",
              "PARAM_VALUE", "MISSION_COUNT", "MISSION_REQUEST_INT", "MISSION_REQUEST", "MISSION_ITEM_INT",
              "MISSION_ITEM", "MISSION_ACK", "MISSION_REQUEST_LIST")
)


def frames(data: bytes) -> list[tuple[int, bytes]]:
    """(message id, payload) of each MAVLink frame in a datagram (no CRC check: only to classify)."""
    out, i = [], 0
    while i + 6 <= len(data):
        n = data[i + 1]
        if data[i] == 0xFD and i + 10 <= len(data):
            out.append((data[i + 7] | data[i + 8] << 8 | data[i + 9] << 16, data[i + 10 : i + 10 + n]))
            i += 12 + n + (13 if data[i + 2] & 1 else 0)
        elif data[i] == 0xFE:
            out.append((data[i + 5], data[i + 6 : i + 6 + n]))
            i += 8 + n
        else:
            break
    return out


class LossyProxy:
    """UDP relay between the FC (which sends its telemetry to :attr:`fc_side_port`) and a GCS
    listening on ``gcs_port``; drops ``loss`` of the datagrams each way.

    Deterministic: a datagram of the request/answer protocols is dropped or not according to
    (seed, direction, its messages' ids and payloads, how many times that same content went this
    way before), so the fate of, say, the second transmission of mission item 3 does not depend
    on how much telemetry happened to pass in between, nor on timing. Other datagrams (telemetry,
    heartbeats) draw from one seeded RNG per direction.

    ``drop_first`` names ``(direction, message id)`` pairs whose first datagram is dropped whatever
    the draw says, so a test can be sure each recovery path is exercised (the draws depend on the
    messages' contents, e.g. on the length of the parameter list)."""

    def __init__(self, gcs_port: int, *, loss: float = 0.1, seed: int = 1, drop_first: frozenset[tuple[str, int]] = frozenset()) -> None:
        self.fc_side = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.fc_side.bind((LOOPBACK, 0))
        self.gcs_side = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.gcs_side.bind((LOOPBACK, 0))
        self.gcs_addr = (LOOPBACK, gcs_port)
        self.fc_addr: tuple[str, int] | None = None
        self.loss = loss
        self.seed = seed
        self._rng_other = {way: random.Random(f"{seed}-{way}") for way in ("up", "down")}
        self._occurrences: dict[bytes, int] = {}
        self._drop_first = set(drop_first)
        self.passed = {"up": 0, "down": 0}
        self.dropped = {"up": 0, "down": 0}
        #: protocol datagrams dropped, per direction
        self.dropped_protocol = {"up": 0, "down": 0}
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="lossy-proxy", daemon=True)

    def _drop(self, way: str, data: bytes) -> tuple[bool, bool]:
        """(drop it?, is it a protocol datagram?)"""
        msgs = frames(data)
        if not any(mid in PROTOCOL_MSGS for mid, _ in msgs):
            return self._rng_other[way].random() < self.loss, False
        for mid, _ in msgs:
            if (way, mid) in self._drop_first:
                self._drop_first.discard((way, mid))
                return True, True
        content = hashlib.sha256(repr((way, msgs)).encode()).digest()
        n = self._occurrences.get(content, 0)
        self._occurrences[content] = n + 1
        key = hashlib.sha256(f"{self.seed}|{n}|".encode() + content).digest()
        return random.Random(int.from_bytes(key[:8], "little")).random() < self.loss, True

    @property
    def fc_side_port(self) -> int:
        return self.fc_side.getsockname()[1]

    def __enter__(self) -> LossyProxy:
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        self._thread.join(timeout=5.0)
        self.fc_side.close()
        self.gcs_side.close()

    def _run(self) -> None:
        socks = [self.fc_side, self.gcs_side]
        while not self._stop.is_set():
            r, _, _ = select.select(socks, [], [], 0.05)
            for s in r:
                try:
                    data, addr = s.recvfrom(65535)
                except OSError:
                    continue
                if s is self.fc_side:
                    self.fc_addr = addr
                    self._forward("down", self.gcs_side, data, self.gcs_addr)
                elif self.fc_addr is not None:
                    self._forward("up", self.fc_side, data, self.fc_addr)

    def _forward(self, way: str, sock: socket.socket, data: bytes, addr: tuple[str, int]) -> None:
        drop, protocol = self._drop(way, data)
        if drop:
            self.dropped[way] += 1
            if protocol:
                self.dropped_protocol[way] += 1
            return
        self.passed[way] += 1
        with contextlib.suppress(OSError):
            sock.sendto(data, addr)
