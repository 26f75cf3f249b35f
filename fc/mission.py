"""The mission: stored items, their validation, and the MAVLink mission protocol (vehicle side).

Upload: ``MISSION_COUNT`` -> ``MISSION_REQUEST_INT`` (we ask for each item in turn, re-asking after
``REQUEST_TIMEOUT_S`` up to ``MAX_RETRIES`` times) -> ``MISSION_ITEM_INT`` -> ... -> ``MISSION_ACK``.
A station that speaks the float protocol (it sent ``MISSION_ITEM`` or ``MISSION_REQUEST``, as
DroneKit does) is asked with ``MISSION_REQUEST``, as ArduPilot remembers per link; a station that
answered no request of this upload yet is re-asked with both requests.
The new mission replaces the stored one only when the upload completes; a bad item ends the
upload with the protocol's error code and leaves the stored mission (and the flight) unchanged.
Download, clear and set-current are answered directly. Timeouts run on the wall clock.

Item 0 is home, as in ArduPilot; AUTO flies from item 1. With no mission stored, a request for
item 0 is answered with home (DroneKit always asks for it).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, replace

from pymavlink.dialects.v20 import ardupilotmega as mavlink

from smcpilot.geo import Home, global_to_ned
from smcpilot.limits import DEFAULT_FENCE, Fence, takeoff_refusal, target_refusal

Address = tuple[str, int]

REQUEST_TIMEOUT_S = 1.0
#: re-requests before an upload is cancelled: 8 s of silence, as ArduPilot's upload timeout (a
#: lossy link — 30 % each way — still completes uploads).
MAX_RETRIES = 8
#: An upload whose station has sent nothing for this long (wall seconds) is abandoned: another
#: station's MISSION_COUNT takes over (the old station gets OPERATION_CANCELLED).
ABANDONED_UPLOAD_S = 2.0
#: for this long (wall seconds) after an upload completed, a re-sent last item gets the ACK again.
REACK_S = 10.0
MAX_ITEMS = 500
#: at most this many stations remembered as speaking the float (non-INT) mission protocol.
MAX_LEGACY_STATIONS = 64

CMD_WAYPOINT = mavlink.MAV_CMD_NAV_WAYPOINT
CMD_LOITER_TIME = mavlink.MAV_CMD_NAV_LOITER_TIME
CMD_RTL = mavlink.MAV_CMD_NAV_RETURN_TO_LAUNCH
CMD_LAND = mavlink.MAV_CMD_NAV_LAND
CMD_TAKEOFF = mavlink.MAV_CMD_NAV_TAKEOFF
CMD_CHANGE_SPEED = mavlink.MAV_CMD_DO_CHANGE_SPEED
SUPPORTED_COMMANDS = frozenset({CMD_WAYPOINT, CMD_LOITER_TIME, CMD_RTL, CMD_LAND, CMD_TAKEOFF, CMD_CHANGE_SPEED})
NAV_WITH_POSITION = frozenset({CMD_WAYPOINT, CMD_LOITER_TIME, CMD_LAND, CMD_TAKEOFF})
GLOBAL_FRAMES = frozenset(
    {
        mavlink.MAV_FRAME_GLOBAL,
        mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT,
        mavlink.MAV_FRAME_GLOBAL_INT,
        mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT,
    }
)
RELATIVE_FRAMES = frozenset({mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT, mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT})


@dataclass(frozen=True)
class MissionItem:
    """One stored item, as ``MISSION_ITEM_INT`` carries it (x, y = lat, lon x 1e7; z = altitude m)."""

    seq: int
    frame: int
    command: int
    current: int
    autocontinue: int
    param1: float
    param2: float
    param3: float
    param4: float
    x: int
    y: int
    z: float

    @classmethod
    def from_msg(cls, m: mavlink.MAVLink_message) -> MissionItem:
        """From ``MISSION_ITEM_INT`` or ``MISSION_ITEM`` (float degrees become 1e7 integers)."""
        if m.get_type() == "MISSION_ITEM":
            x = int(round(m.x * 1e7)) if math.isfinite(m.x) else 2**31 - 1
            y = int(round(m.y * 1e7)) if math.isfinite(m.y) else 2**31 - 1
            frame = {mavlink.MAV_FRAME_GLOBAL: mavlink.MAV_FRAME_GLOBAL_INT,
                     mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT: mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT}.get(m.frame, m.frame)  # fmt: skip
        else:
            x, y, frame = m.x, m.y, m.frame
        return cls(m.seq, frame, m.command, m.current, m.autocontinue, m.param1, m.param2, m.param3, m.param4, x, y, m.z)

    @property
    def lat_deg(self) -> float:
        return self.x * 1e-7

    @property
    def lon_deg(self) -> float:
        return self.y * 1e-7


def validate(item: MissionItem) -> int:
    """``MAV_MISSION_ACCEPTED`` or the protocol's error code for this item."""
    if item.command not in SUPPORTED_COMMANDS and item.seq != 0:
        return mavlink.MAV_MISSION_UNSUPPORTED
    if item.command in NAV_WITH_POSITION or item.seq == 0:
        if item.frame not in GLOBAL_FRAMES:
            return mavlink.MAV_MISSION_UNSUPPORTED_FRAME
        if not -90 * 10**7 <= item.x <= 90 * 10**7:
            return mavlink.MAV_MISSION_INVALID_PARAM5_X
        if not -180 * 10**7 <= item.y <= 180 * 10**7:
            return mavlink.MAV_MISSION_INVALID_PARAM6_Y
        if not math.isfinite(item.z) or not -1000.0 <= item.z <= 10000.0:
            return mavlink.MAV_MISSION_INVALID_PARAM7
    if item.command in (CMD_WAYPOINT, CMD_LOITER_TIME):
        if not math.isfinite(item.param1) or item.param1 < 0.0 or item.param1 > 3600.0:
            return mavlink.MAV_MISSION_INVALID_PARAM1
        if item.command == CMD_WAYPOINT and not (math.isfinite(item.param2) and item.param2 >= 0.0):
            return mavlink.MAV_MISSION_INVALID_PARAM2
    if item.command == CMD_CHANGE_SPEED:
        if not math.isfinite(item.param2) or not (item.param2 == -1.0 or 0.0 < item.param2 <= 50.0):
            return mavlink.MAV_MISSION_INVALID_PARAM2
    if item.command == CMD_TAKEOFF and item.seq != 0 and not 0.5 <= item.z <= 500.0:
        return mavlink.MAV_MISSION_INVALID_PARAM7
    return mavlink.MAV_MISSION_ACCEPTED


def fence_refusal(item: MissionItem, home: Home, fence: Fence) -> str | None:
    """Why ``item`` (valid by :func:`validate`) flies to a target outside ``fence`` or below
    ground, or None: the rule every target passes (:mod:`smcpilot.limits`). Item 0 (home), and
    items with no target (speed, RTL) pass; a take-off is checked for its altitude, a loiter or
    land at latitude/longitude 0/0 ("here") for its altitude only."""
    if item.seq == 0 or item.command not in NAV_WITH_POSITION:
        return None
    alt = item.z if item.frame in RELATIVE_FRAMES else item.z - home.alt_m
    if item.command == CMD_TAKEOFF:
        return takeoff_refusal(alt, fence)
    if item.command != CMD_WAYPOINT and item.x == 0 and item.y == 0:
        if item.command == CMD_LAND or item.z <= 0:
            return None
        return target_refusal(0.0, 0.0, alt, fence)
    n, e, _ = global_to_ned(home, item.lat_deg, item.lon_deg, home.alt_m)
    if item.command == CMD_LAND:
        alt = max(alt, 0.0)  # a landing comes down to the ground wherever it is given
    return target_refusal(n, e, alt, fence)


_RESULT_NAMES = {v: e.name for v, e in mavlink.enums["MAV_MISSION_RESULT"].items()}

SendTo = Callable[[mavlink.MAVLink_message, Address], None]


def _nothing() -> None:
    return None


def _nothing_at(seq: int) -> None:
    return None


class MissionStore:
    """The stored mission the vehicle flies: items (0 is home) and the current one.

    The commander owns it (AUTO flies it); the ground protocol (:class:`MissionProtocol`, at the
    FC's edge) fills it and reads it. ``on_change`` hears a new or cleared mission,
    ``on_set_current`` a new current item (the commander restarts AUTO's item)."""

    def __init__(self, on_change: Callable[[], None] = _nothing, on_set_current: Callable[[int], None] = _nothing_at) -> None:
        self.items: list[MissionItem] = []
        self.current = 0
        self.on_change = on_change
        self.on_set_current = on_set_current

    def set_current(self, seq: int) -> bool:
        """Make item ``seq`` current (False: no such item)."""
        if not 0 <= seq < len(self.items):
            return False
        self.current = seq
        self.on_set_current(seq)
        return True


class MissionProtocol:
    """Vehicle side of the mission protocol, over a :class:`MissionStore`. ``send_to`` sends to one
    ground station."""

    def __init__(
        self,
        store: MissionStore,
        mav: mavlink.MAVLink,
        send_to: SendTo,
        home: Callable[[], Home] | None = None,
        fence: Callable[[], Fence] | None = None,
    ) -> None:
        """``home``: the home position now, sent as item 0 while no mission is stored (None: no
        item 0 then). ``fence``: the geofence now; an uploaded item outside it ends the upload
        (:func:`fence_refusal`; None: the default fence)."""
        self.store = store
        self.mav = mav
        self._home = home
        self._fence = fence if fence is not None else (lambda: DEFAULT_FENCE)
        #: hears (reason, text) of a refused item: the GCS handler counts it and says why.
        self.on_reject: Callable[[str, str], None] = lambda reason, text: None
        #: stations (addresses) that used the float protocol (MISSION_ITEM / MISSION_REQUEST).
        self.legacy_stations: set[Address] = set()
        self._send_to = send_to
        # Upload in progress
        self._partner: Address | None = None
        self._partner_heard_s = -math.inf
        #: MISSION_ACKs with an error sent (refused counts, items, uploads cancelled), and
        #: items ignored (no upload with that station, or out of sequence): rejected packets.
        self.refused = 0
        self.ignored = 0
        self._partner_sys = 0
        self._partner_comp = 0
        self._count = 0
        self._incoming: list[MissionItem] = []
        self._deadline = 0.0
        self._retries = 0
        #: the last completed upload (station, item count, wall s): a re-sent last item from it is
        #: answered with ACCEPTED again (the first ACK was lost).
        self._last_upload: tuple[Address, int, float] | None = None
        self.uploads_completed = 0
        self.uploads_failed = 0

    @property
    def items(self) -> list[MissionItem]:
        """The stored items (the store's)."""
        return self.store.items

    @property
    def current(self) -> int:
        return self.store.current

    @property
    def uploading(self) -> bool:
        return self._partner is not None

    # -- helpers --------------------------------------------------------------------------------
    def _ack(self, addr: Address, sysid: int, compid: int, result: int) -> None:
        if result != mavlink.MAV_MISSION_ACCEPTED:
            self.refused += 1
        self._send_to(self.mav.mission_ack_encode(sysid, compid, result, mavlink.MAV_MISSION_TYPE_MISSION), addr)

    def note_legacy(self, addr: Address) -> None:
        """Remember that the station at ``addr`` speaks the float mission protocol."""
        if addr not in self.legacy_stations:
            if len(self.legacy_stations) >= MAX_LEGACY_STATIONS:
                self.legacy_stations.clear()
            self.legacy_stations.add(addr)

    def _request(self, retry: bool = False) -> None:
        """Ask the partner for the next item: ``MISSION_REQUEST`` to a float-protocol station,
        else ``MISSION_REQUEST_INT`` (and on a retry with no item of this upload received yet,
        both: a station that ignores ``MISSION_REQUEST_INT`` is never stuck)."""
        assert self._partner is not None
        seq = len(self._incoming)
        legacy = self._partner in self.legacy_stations
        if not legacy:
            self._send_to(
                self.mav.mission_request_int_encode(self._partner_sys, self._partner_comp, seq, mavlink.MAV_MISSION_TYPE_MISSION),
                self._partner,
            )
        if legacy or (retry and seq == 0):
            self._send_to(
                self.mav.mission_request_encode(self._partner_sys, self._partner_comp, seq, mavlink.MAV_MISSION_TYPE_MISSION),
                self._partner,
            )

    def _end_upload(self) -> None:
        self._partner = None
        self._incoming = []

    # -- incoming -------------------------------------------------------------------------------
    def on_count(self, m: mavlink.MAVLink_message, addr: Address, now_s: float) -> None:
        if getattr(m, "mission_type", 0) != mavlink.MAV_MISSION_TYPE_MISSION:
            self._ack(addr, m.get_srcSystem(), m.get_srcComponent(), mavlink.MAV_MISSION_UNSUPPORTED)
            return
        if self._partner is not None and self._partner != addr:
            if now_s - self._partner_heard_s < ABANDONED_UPLOAD_S:
                self._ack(addr, m.get_srcSystem(), m.get_srcComponent(), mavlink.MAV_MISSION_DENIED)
                return
            self.uploads_failed += 1  # abandoned: the new station takes over
            self._ack(self._partner, self._partner_sys, self._partner_comp, mavlink.MAV_MISSION_OPERATION_CANCELLED)
            self._end_upload()
        if m.count > MAX_ITEMS:
            self._ack(addr, m.get_srcSystem(), m.get_srcComponent(), mavlink.MAV_MISSION_NO_SPACE)
            return
        if m.count == 0:
            self._end_upload()
            self.store.items = []
            self.store.current = 0
            self.store.on_change()
            self._ack(addr, m.get_srcSystem(), m.get_srcComponent(), mavlink.MAV_MISSION_ACCEPTED)
            return
        self._partner = addr
        self._partner_heard_s = now_s
        self._partner_sys = m.get_srcSystem()
        self._partner_comp = m.get_srcComponent()
        self._count = m.count
        self._incoming = []
        self._retries = 0
        self._deadline = now_s + REQUEST_TIMEOUT_S
        self._request()

    def on_item(self, m: mavlink.MAVLink_message, addr: Address, now_s: float) -> None:
        if m.get_type() == "MISSION_ITEM":
            self.note_legacy(addr)
        else:
            self.legacy_stations.discard(addr)
        if self._partner is None or addr != self._partner:
            done = self._last_upload
            if done is not None and done[0] == addr and m.seq == done[1] - 1 and now_s - done[2] < REACK_S:
                # The station re-sent its last item: our ACCEPTED was lost on the way. Say it again.
                self._ack(addr, m.get_srcSystem(), m.get_srcComponent(), mavlink.MAV_MISSION_ACCEPTED)
                return
            self.ignored += 1
            return  # not in an upload with this station: ignore, as ArduPilot does
        if getattr(m, "mission_type", 0) != mavlink.MAV_MISSION_TYPE_MISSION:
            return
        self._partner_heard_s = now_s
        expected = len(self._incoming)
        if m.seq != expected:
            self.ignored += 1
            if m.seq < expected:  # a late duplicate: ask for the one we need
                self._request()
                self._deadline = now_s + REQUEST_TIMEOUT_S
            return
        item = MissionItem.from_msg(m)
        result = validate(item)
        why = None
        if result == mavlink.MAV_MISSION_ACCEPTED and self._home is not None:
            why = fence_refusal(item, self._home(), self._fence())
            if why is not None:
                result = mavlink.MAV_MISSION_INVALID_PARAM7 if "altitude" in why else mavlink.MAV_MISSION_INVALID_PARAM5_X
        if result != mavlink.MAV_MISSION_ACCEPTED:
            self.uploads_failed += 1
            if why is not None:
                self.on_reject("mission_fence", f"Mission item {item.seq} refused: {why}")
            else:
                self.on_reject("mission_item_invalid", f"Mission item {item.seq} refused ({_RESULT_NAMES.get(result, result)})")
            self._ack(addr, self._partner_sys, self._partner_comp, result)
            self._end_upload()
            return
        self._incoming.append(item)
        self._retries = 0
        self._deadline = now_s + REQUEST_TIMEOUT_S
        if len(self._incoming) < self._count:
            self._request()
            return
        self.store.items = [replace(it, current=0) for it in self._incoming]
        self.store.current = 1 if len(self.store.items) > 1 else 0
        self.uploads_completed += 1
        self._last_upload = (addr, self._count, now_s)
        self._ack(addr, self._partner_sys, self._partner_comp, mavlink.MAV_MISSION_ACCEPTED)
        self._end_upload()
        self.store.on_change()

    def on_request_list(self, m: mavlink.MAVLink_message, addr: Address) -> None:
        if getattr(m, "mission_type", 0) != mavlink.MAV_MISSION_TYPE_MISSION:
            self._ack(addr, m.get_srcSystem(), m.get_srcComponent(), mavlink.MAV_MISSION_UNSUPPORTED)
            return
        self._send_to(
            self.mav.mission_count_encode(m.get_srcSystem(), m.get_srcComponent(), len(self.items), mavlink.MAV_MISSION_TYPE_MISSION),
            addr,
        )

    def _home_item(self) -> MissionItem | None:
        """Item 0 while no mission is stored: home (AMSL), as ArduPilot answers; None: no home."""
        if self._home is None:
            return None
        h = self._home()
        return MissionItem(0, mavlink.MAV_FRAME_GLOBAL_INT, CMD_WAYPOINT, 0, 1, 0.0, 0.0, 0.0, 0.0,
                           int(round(h.lat_deg * 1e7)), int(round(h.lon_deg * 1e7)), float(h.alt_m))  # fmt: skip

    def on_request(self, m: mavlink.MAVLink_message, addr: Address, as_int: bool) -> None:
        if getattr(m, "mission_type", 0) != mavlink.MAV_MISSION_TYPE_MISSION:
            return
        if not as_int:
            self.note_legacy(addr)
        home = self._home_item() if m.seq == 0 and not self.items else None
        if home is None and not 0 <= m.seq < len(self.items):
            self._ack(addr, m.get_srcSystem(), m.get_srcComponent(), mavlink.MAV_MISSION_INVALID_SEQUENCE)
            return
        it = home if home is not None else self.items[m.seq]
        cur = 1 if m.seq == self.current else 0
        sysid, compid = m.get_srcSystem(), m.get_srcComponent()
        if as_int:
            msg = self.mav.mission_item_int_encode(
                sysid, compid, it.seq, it.frame, it.command, cur, it.autocontinue,
                it.param1, it.param2, it.param3, it.param4, it.x, it.y, it.z, mavlink.MAV_MISSION_TYPE_MISSION,
            )  # fmt: skip
        else:
            frame = {mavlink.MAV_FRAME_GLOBAL_INT: mavlink.MAV_FRAME_GLOBAL,
                     mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT: mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT}.get(it.frame, it.frame)  # fmt: skip
            msg = self.mav.mission_item_encode(
                sysid, compid, it.seq, frame, it.command, cur, it.autocontinue,
                it.param1, it.param2, it.param3, it.param4, it.x * 1e-7, it.y * 1e-7, it.z, mavlink.MAV_MISSION_TYPE_MISSION,
            )  # fmt: skip
        self._send_to(msg, addr)

    def on_clear(self, m: mavlink.MAVLink_message, addr: Address) -> None:
        if getattr(m, "mission_type", 0) not in (mavlink.MAV_MISSION_TYPE_MISSION, mavlink.MAV_MISSION_TYPE_ALL):
            self._ack(addr, m.get_srcSystem(), m.get_srcComponent(), mavlink.MAV_MISSION_UNSUPPORTED)
            return
        self.store.items = []
        self.store.current = 0
        self.store.on_change()
        self._ack(addr, m.get_srcSystem(), m.get_srcComponent(), mavlink.MAV_MISSION_ACCEPTED)

    def set_current(self, seq: int) -> bool:
        return self.store.set_current(seq)

    def tick(self, now_s: float) -> None:
        """Re-request a missing item after the timeout; give up after ``MAX_RETRIES``."""
        if self._partner is None or now_s < self._deadline:
            return
        if self._retries >= MAX_RETRIES:
            self.uploads_failed += 1
            self._ack(self._partner, self._partner_sys, self._partner_comp, mavlink.MAV_MISSION_OPERATION_CANCELLED)
            self._end_upload()
            return
        self._retries += 1
        self._deadline = now_s + REQUEST_TIMEOUT_S
        self._request(retry=True)
