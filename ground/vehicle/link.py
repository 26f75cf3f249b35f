"""The link to one vehicle: the connection, the receiver and heartbeat threads, the latest
telemetry, subscriptions, and the waits on the vehicle's simulated clock.

:class:`Link` is the connection half of :class:`~ground.vehicle.Vehicle` (its base class; the
vehicle checks the settings). Threads: exactly one thread (the receiver) reads the link; it folds
each message into the telemetry (:class:`~ground.vehicle.telemetry.TelemetryParser`), feeds the
subscribers and wakes the waiters. Every send goes through one lock (the link is not
thread-safe). A GCS ``HEARTBEAT`` goes out every ``heartbeat_period_s`` wall seconds.

Clocks: every ``wait_*`` timeout is in simulated seconds (``timeout_sim_s``, the vehicle's
``time_boot_ms``), with a wall-clock safety limit (``wall_margin_s + wall_per_sim_s *
timeout_sim_s``) and a stall limit (``stall_timeout_s`` wall seconds without a message).
"""

from __future__ import annotations

import logging
import math
import os
import threading
import time
from collections.abc import Callable, Iterable
from types import TracebackType
from typing import Self

from pymavlink.dialects.v20 import ardupilotmega as mavlink

from ground.vehicle.errors import ConnectTimeout, VehicleTimeout
from ground.vehicle.modes import mode_name, mode_number
from ground.vehicle.subscription import Subscription
from ground.vehicle.telemetry import StatusText, StatusTextAssembler, Telemetry, TelemetryParser
from smcpilot.errors import ConfigError, LinkClosedError
from smcpilot.link import Address, LinkCounters, MavlinkUdp
from smcpilot.signing import KEY_BYTES, Signing, load_key

__all__ = ["GCS_COMPONENT_ID", "GCS_SYSTEM_ID", "Link"]

log = logging.getLogger(__name__)

#: Our MAVLink identity: a ground station (MAV_COMP_ID_MISSIONPLANNER).
GCS_SYSTEM_ID = 255
GCS_COMPONENT_ID = mavlink.MAV_COMP_ID_MISSIONPLANNER  # 190
_STATUSTEXT = mavlink.MAVLink_statustext_message
#: other vehicles whose telemetry a link keeps (a swarm's; smcpilot flies at most 64).
MAX_OTHER_VEHICLES = 255


class Link:
    """The connection to one vehicle (see the module docstring); the base of
    :class:`~ground.vehicle.Vehicle`, which documents and checks the settings.

    ``url`` is a :mod:`smcpilot.link` URL (``udpin:HOST:PORT`` or ``udpout:HOST:PORT``);
    ``system_id`` the vehicle to talk to (None: the first heard). Times in seconds: wall clock
    for ``connect_timeout_s``, ``wall_margin_s``, ``stall_timeout_s``, ``heartbeat_period_s``;
    ``wall_per_sim_s`` is wall seconds allowed per simulated second of a wait.
    """

    def __init__(
        self,
        url: str,
        *,
        system_id: int | None = None,
        connect_timeout_s: float = 15.0,
        wall_margin_s: float = 30.0,
        wall_per_sim_s: float = 3.0,
        stall_timeout_s: float = 10.0,
        statustext_history: int = 100,
        heartbeat_period_s: float = 1.0,
        signing_key: bytes | str | os.PathLike[str] | None = None,
    ) -> None:
        self.url = url
        #: MAVLink 2 signing (None: unsigned): a 32-byte key, or a key file (smcpilot.signing.load_key).
        if signing_key is None:
            self.signing: Signing | None = None
        elif isinstance(signing_key, (bytes, bytearray)):
            if len(signing_key) != KEY_BYTES:
                raise ConfigError(f"signing_key must be {KEY_BYTES} bytes or a key file, got {len(signing_key)} bytes")
            self.signing = Signing(bytes(signing_key))
        else:
            self.signing = Signing(load_key(signing_key))
        self.connect_timeout_s = float(connect_timeout_s)
        self.wall_margin_s = float(wall_margin_s)
        self.wall_per_sim_s = float(wall_per_sim_s)
        self.stall_timeout_s = float(stall_timeout_s)
        self.heartbeat_period_s = float(heartbeat_period_s)
        self._wanted_system = system_id

        self._link: MavlinkUdp | None = None
        self._tx_lock = threading.Lock()
        self._cond = threading.Condition()
        self._parser = TelemetryParser(system_id, statustext_history)
        #: other vehicles heard on the same link (a swarm's router sends every vehicle's telemetry).
        self._others: dict[int, TelemetryParser] = {}
        self._texts = StatusTextAssembler()
        self._subs: tuple[Subscription, ...] = ()
        self._subs_lock = threading.Lock()
        self._stop = threading.Event()
        self._threads: list[threading.Thread] = []
        self._rx_error: BaseException | None = None

    @property
    def _state(self) -> Telemetry:
        return self._parser.state

    # -------------------------------------------------------------------------------- lifecycle
    def open(self) -> Self:
        """Open the link and start the receiver and heartbeat threads (does not wait for the vehicle)."""
        if self._link is not None:
            return self
        self._link = MavlinkUdp(
            self.url, source_system=GCS_SYSTEM_ID, source_component=GCS_COMPONENT_ID, signing=self.signing
        )
        self._stop.clear()
        self._threads = [
            threading.Thread(target=self._rx_loop, name=f"vehicle-rx {self.url}", daemon=True),
            threading.Thread(target=self._heartbeat_loop, name=f"vehicle-hb {self.url}", daemon=True),
        ]
        for t in self._threads:
            t.start()
        return self

    def wait_heartbeat(self, timeout_s: float | None = None) -> Self:
        """Wait up to ``timeout_s`` wall seconds (default ``connect_timeout_s``) for the vehicle's
        HEARTBEAT; raise :class:`ConnectTimeout` saying where we listened."""
        timeout = self.connect_timeout_s if timeout_s is None else timeout_s
        deadline = time.monotonic() + timeout
        with self._cond:
            while self._state.heartbeats == 0:
                remaining = deadline - time.monotonic()
                if remaining <= 0:
                    break
                self._cond.wait(min(remaining, 0.2))
            got = self._state.heartbeats > 0
        if not got:
            link = self._require_link()
            where = (
                f"listening on {link.local_address[0]}:{link.local_address[1]}"
                if link.endpoint.mode == "in"
                else f"writing to {link.endpoint.host}:{link.endpoint.port}"
            )
            hint = " (is the FC running with --gcs udp:HOST:PORT pointing here?)" if link.endpoint.mode == "in" else ""
            raise ConnectTimeout(
                f"no HEARTBEAT from a vehicle within {timeout:g} s wall, {where}{hint}", what="vehicle HEARTBEAT"
            )
        return self

    def connect(self, timeout_s: float | None = None) -> Self:
        """:meth:`open`, then :meth:`wait_heartbeat`; closes again on failure."""
        self.open()
        try:
            return self.wait_heartbeat(timeout_s)
        except BaseException:
            self.close()
            raise

    def close(self) -> None:
        """Stop the threads and close the link (idempotent)."""
        self._stop.set()
        for t in self._threads:
            if t is not threading.current_thread():
                t.join(timeout=2.0)
        self._threads = []
        link, self._link = self._link, None
        if link is not None:
            with self._tx_lock:
                link.close()

    def __enter__(self) -> Self:
        return self.connect()

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None) -> None:
        self.close()

    @property
    def local_address(self) -> Address:
        """``(host, port)`` our socket is bound to (after :meth:`open`)."""
        return self._require_link().local_address

    @property
    def target_system(self) -> int:
        """The vehicle's system id (from its HEARTBEAT; the wanted one, or 1, before that)."""
        s = self._state.system_id
        return s if s is not None else (self._wanted_system or 1)

    @property
    def target_component(self) -> int:
        c = self._state.component_id
        return c if c is not None else mavlink.MAV_COMP_ID_AUTOPILOT1

    def _require_link(self) -> MavlinkUdp:
        link = self._link
        if link is None:
            raise LinkClosedError(f"vehicle connection {self.url} is not open")
        return link

    @property
    def link_counters(self) -> LinkCounters:
        """This station's own link counters (e.g. packets it dropped for a bad signature)."""
        return self._require_link().counters

    @property
    def mav(self) -> mavlink.MAVLink:
        """pymavlink encoder for building messages to :meth:`send` (``vehicle.mav.xxx_encode(...)``)."""
        return self._require_link().mav

    # -------------------------------------------------------------------------------- sending
    def send(self, msg: mavlink.MAVLink_message) -> None:
        """Send one message (thread-safe)."""
        link = self._require_link()
        with self._tx_lock:
            link.send(msg)

    def _heartbeat_loop(self) -> None:
        while not self._stop.is_set():
            link = self._link
            if link is None:
                return
            try:
                msg = link.mav.heartbeat_encode(
                    mavlink.MAV_TYPE_GCS, mavlink.MAV_AUTOPILOT_INVALID, 0, 0, mavlink.MAV_STATE_ACTIVE
                )
                with self._tx_lock:
                    if link.closed:
                        return
                    link.send(msg)
            except LinkClosedError:
                return
            self._stop.wait(self.heartbeat_period_s)

    # -------------------------------------------------------------------------------- receiving
    def _rx_loop(self) -> None:
        link = self._link
        assert link is not None
        while not self._stop.is_set():
            try:
                batch = link.recv(0.1)
            except LinkClosedError:
                return
            except Exception as exc:  # pragma: no cover - defensive: keep the reason for waiters
                self._rx_error = exc
                log.exception("vehicle receiver failed")
                return
            if not batch:
                continue
            accepted: list[mavlink.MAVLink_message] = []
            with self._cond:
                for raw, addr in batch:
                    # STATUSTEXT chunks are joined first: everyone downstream sees whole texts
                    # (type(), not .id: STATUSTEXT's own field "id" hides the message id)
                    for msg in self._texts.feed(raw) if type(raw) is _STATUSTEXT else (raw,):
                        if self._parser.ingest(msg, addr):
                            accepted.append(msg)
                        else:
                            self._ingest_other(msg, addr)
                self._cond.notify_all()
            subs = self._subs
            if subs and accepted:
                for msg in accepted:
                    t = msg.get_type()
                    for sub in subs:
                        if sub.wants(t):
                            sub._deliver(msg)

    def _ingest_other(self, msg: mavlink.MAVLink_message, addr: Address) -> None:
        """Keep the telemetry of another vehicle heard here (its first autopilot HEARTBEAT adds it)."""
        src = msg.get_srcSystem()
        parser = self._others.get(src)
        if parser is None:
            if (msg.get_type() != "HEARTBEAT" or msg.type == mavlink.MAV_TYPE_GCS or msg.autopilot == mavlink.MAV_AUTOPILOT_INVALID
                    or src == self._state.system_id or len(self._others) >= MAX_OTHER_VEHICLES):  # fmt: skip
                return
            parser = self._others[src] = TelemetryParser(src, statustext_history=10)
        parser.ingest(msg, addr)

    def vehicles_heard(self) -> dict[int, Telemetry]:
        """Every vehicle heard on this link by system id (ours and, e.g. behind a swarm's router,
        the others), each one's latest telemetry."""
        with self._cond:
            out = {sid: p.state for sid, p in self._others.items()}
            if self._state.system_id is not None:
                out[self._state.system_id] = self._state
        return dict(sorted(out.items()))

    # ----------------------------------------------------------------------------- subscriptions
    def subscribe(
        self,
        types: str | Iterable[str] | None = None,
        callback: Callable[[mavlink.MAVLink_message], None] | None = None,
        *,
        maxsize: int = 10000,
    ) -> Subscription:
        """Receive messages of ``types`` (names like ``"STATUSTEXT"``; None = all) from the vehicle,
        from now on: into the subscription's queue, or to ``callback`` (on the receiver thread)."""
        type_set = None if types is None else frozenset([types] if isinstance(types, str) else types)
        sub = Subscription(self, type_set, callback, maxsize)
        with self._subs_lock:
            self._subs = self._subs + (sub,)
        return sub

    def _unsubscribe(self, sub: Subscription) -> None:
        with self._subs_lock:
            self._subs = tuple(s for s in self._subs if s is not sub)

    # -------------------------------------------------------------------------------- telemetry
    @property
    def telemetry(self) -> Telemetry:
        """The latest telemetry (an immutable snapshot)."""
        return self._state

    @property
    def sim_time_s(self) -> float | None:
        return self._state.sim_time_s

    @property
    def armed(self) -> bool:
        return self._state.armed

    @property
    def mode(self) -> str | None:
        """Current flight-mode name (from the last HEARTBEAT)."""
        return self._state.mode_name

    @property
    def position_ned_m(self) -> tuple[float, float, float] | None:
        return self._state.position_ned_m

    @property
    def altitude_m(self) -> float | None:
        return self._state.altitude_m

    @property
    def statustexts(self) -> tuple[StatusText, ...]:
        return self._state.statustexts

    # ------------------------------------------------------------------------------------ waits
    def wait_for(
        self,
        predicate: Callable[[Telemetry], bool],
        timeout_sim_s: float,
        *,
        what: str,
        value: Callable[[Telemetry], object] | None = None,
    ) -> Telemetry:
        """Wait until ``predicate(telemetry)`` holds; return that telemetry.

        ``timeout_sim_s`` counts simulated seconds from the vehicle's time now. Also gives up when
        the wall clock passes ``wall_margin_s + wall_per_sim_s * timeout_sim_s``, or when nothing
        has come from the vehicle for ``stall_timeout_s`` wall seconds (simulator stopped, link
        down). Raises :class:`VehicleTimeout` naming ``what``, the last ``value(telemetry)`` and
        the simulated time.
        """
        if not (math.isfinite(timeout_sim_s) and timeout_sim_s >= 0):
            raise ConfigError(f"timeout_sim_s must be a finite number >= 0, got {timeout_sim_s!r}")
        self._require_link()
        wall_start = time.monotonic()
        wall_deadline = wall_start + self.wall_margin_s + self.wall_per_sim_s * timeout_sim_s
        with self._cond:
            st = self._state
            sim_start = st.sim_time_s
            while True:
                st = self._state
                if predicate(st):
                    return st
                now = time.monotonic()
                if sim_start is None and st.sim_time_s is not None:
                    sim_start = st.sim_time_s
                why = None
                if sim_start is not None and st.sim_time_s is not None and st.sim_time_s - sim_start >= timeout_sim_s:
                    why = f"timed out after {timeout_sim_s:g} s simulated"
                elif now >= wall_deadline:
                    why = f"gave up after {now - wall_start:.1f} s wall (safety limit; simulated time advanced too slowly)"
                else:
                    last_rx = st.last_message_wall_s if st.last_message_wall_s is not None else wall_start
                    silent = now - max(last_rx, wall_start)
                    if silent >= self.stall_timeout_s:
                        why = f"gave up: nothing from the vehicle for {silent:.1f} s wall (simulator stopped or link down)"
                    elif self._rx_error is not None or self._link is None:
                        why = "gave up: the connection closed"
                if why is not None:
                    last = value(st) if value is not None else None
                    t_txt = "unknown" if st.sim_time_s is None else f"{st.sim_time_s:.2f} s"
                    raise VehicleTimeout(
                        f"{why} waiting for {what}; last value {_fmt(last)}; sim time {t_txt}",
                        what=what,
                        last_value=last,
                        sim_time_s=st.sim_time_s,
                    )
                self._cond.wait(0.1)

    def wait_armed(self, timeout_sim_s: float = 5.0) -> Telemetry:
        return self.wait_for(lambda s: s.armed, timeout_sim_s, what="armed", value=lambda s: "armed" if s.armed else "disarmed")

    def wait_disarmed(self, timeout_sim_s: float = 60.0) -> Telemetry:
        return self.wait_for(
            lambda s: not s.armed and s.heartbeats > 0,
            timeout_sim_s,
            what="disarmed",
            value=lambda s: f"{'armed' if s.armed else 'disarmed'}, altitude {_fmt(s.altitude_m)} m",
        )

    def wait_mode(self, name: str | int, timeout_sim_s: float = 5.0) -> Telemetry:
        number = mode_number(name)
        return self.wait_for(
            lambda s: s.mode_number == number, timeout_sim_s, what=f"mode {mode_name(number)}", value=lambda s: s.mode_name
        )

    def wait_altitude(self, alt_m: float, tol_m: float = 0.3, timeout_sim_s: float = 30.0) -> Telemetry:
        """Wait until the height above home is within ``tol_m`` of ``alt_m`` (metres, up)."""
        return self.wait_for(
            lambda s: s.altitude_m is not None and abs(s.altitude_m - alt_m) <= tol_m,
            timeout_sim_s,
            what=f"altitude {alt_m:g} ± {tol_m:g} m",
            value=lambda s: None if s.altitude_m is None else f"{s.altitude_m:.2f} m",
        )

    def wait_position_ned(
        self,
        north_m: float,
        east_m: float,
        down_m: float,
        tol_m: float = 0.5,
        timeout_sim_s: float = 30.0,
        *,
        max_speed_mps: float | None = None,
    ) -> Telemetry:
        """Wait until the vehicle is within ``tol_m`` (3-D distance) of the NED point, and slower
        than ``max_speed_mps`` if given."""
        target = (north_m, east_m, down_m)

        def ok(s: Telemetry) -> bool:
            if s.position_ned_m is None or math.dist(s.position_ned_m, target) > tol_m:
                return False
            return max_speed_mps is None or (s.velocity_ned_mps is not None and math.hypot(*s.velocity_ned_mps) <= max_speed_mps)

        def val(s: Telemetry) -> object:
            if s.position_ned_m is None:
                return None
            n, e, d = s.position_ned_m
            return f"NED ({n:.2f}, {e:.2f}, {d:.2f}) m, {math.dist(s.position_ned_m, target):.2f} m away"

        return self.wait_for(
            ok, timeout_sim_s, what=f"position NED ({north_m:g}, {east_m:g}, {down_m:g}) ± {tol_m:g} m", value=val
        )

    def wait_landed_state(self, state: str, timeout_sim_s: float = 30.0) -> Telemetry:
        """Wait for EXTENDED_SYS_STATE landed_state ``"ON_GROUND"``, ``"IN_AIR"``, ..."""
        want = state.upper()
        return self.wait_for(
            lambda s: s.landed_state_name == want, timeout_sim_s, what=f"landed state {want}", value=lambda s: s.landed_state_name
        )

    def wait_statustext(self, contains: str, timeout_sim_s: float = 10.0, *, since: int = 0) -> StatusText:
        """Wait for a STATUSTEXT containing ``contains`` (case-insensitive) among the history
        entries from index ``since`` on (``len(vehicle.statustexts)`` before the action)."""
        needle = contains.lower()

        def find(s: Telemetry) -> StatusText | None:
            return next((x for x in s.statustexts[since:] if needle in x.text.lower()), None)

        st = self.wait_for(
            lambda s: find(s) is not None,
            timeout_sim_s,
            what=f"STATUSTEXT containing {contains!r}",
            value=lambda s: s.last_statustext.text if s.last_statustext else None,
        )
        found = find(st)
        assert found is not None
        return found

    def wait_sim_time(self, sim_time_s: float) -> Telemetry:
        """Wait until the vehicle's simulated clock reaches ``sim_time_s``."""
        now = self._state.sim_time_s or 0.0
        return self.wait_for(
            lambda s: s.sim_time_s is not None and s.sim_time_s >= sim_time_s,
            max(0.0, sim_time_s - now) + 1.0,
            what=f"sim time {sim_time_s:g} s",
            value=lambda s: s.sim_time_s,
        )

    def sleep_sim(self, duration_s: float) -> Telemetry:
        """Let ``duration_s`` simulated seconds pass."""
        start = self._state.sim_time_s
        if start is None:
            st = self.wait_for(lambda s: s.sim_time_s is not None, 5.0, what="simulated time")
            start = st.sim_time_s
        assert start is not None
        return self.wait_sim_time(start + duration_s)


def _fmt(value: object) -> str:
    if value is None:
        return "none"
    if isinstance(value, float):
        return f"{value:.3g}"
    return str(value)
