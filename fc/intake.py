"""The ground link's intake: received datagrams queued by importance, handled within a budget.

The real-time loop (:mod:`fc.app`) takes datagrams off the ground socket unparsed (cheap), files
each here by what its header says it carries, and parses and handles them, most important and
oldest first, within a bounded share of each control period (docs/gcs-protocol.md, "The loop
first"). What does not fit waits for a later period; when the queue is full, the oldest datagram
of the least important class is dropped. Every datagram is counted: queued, handled, handled in a
later period than it arrived (deferred), dropped, by class.

Classes, most important first (:data:`CLASS_NAMES`):

0. ``critical`` — what makes the vehicle safe: ``SET_MODE``, and ``COMMAND_LONG``/``COMMAND_INT``
   arm/disarm, set mode, land, return to launch;
1. ``command`` — every other command, set-points, parameter changes, mission uploads, signing;
2. ``heartbeat`` — ground-station heartbeats (they keep the GCS-loss failsafe away);
3. ``request`` — telemetry requests: parameter and mission reads, stream rates, message requests,
   MAVLink-FTP;
4. ``other`` — anything else: unknown messages, bytes that are not MAVLink, and the simulator
   link's datagrams from other addresses than the simulator's.

A datagram holding several packets takes the class of its most important one. The class is read
from the header (and a command's id from its payload) before the CRC is checked: a forged or
garbled datagram can claim a class, and is then refused when parsed as before (signing, when on,
is checked then too). Pure: no sockets, no clocks (the caller passes the period number).
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field
from typing import Generic, TypeVar

from pymavlink.dialects.v20 import ardupilotmega as M

CRITICAL, COMMAND, HEARTBEAT, REQUEST, OTHER = range(5)
CLASS_NAMES = ("critical", "command", "heartbeat", "request", "other")
#: datagrams waiting at most, all classes together; one more drops the least important oldest.
DEFAULT_CAPACITY = 256
#: packets of one datagram looked at for its class.
_MAX_PACKETS = 16

_V2, _V1 = M.PROTOCOL_MARKER_V2, M.PROTOCOL_MARKER_V1
_COMMANDS = (M.MAVLINK_MSG_ID_COMMAND_LONG, M.MAVLINK_MSG_ID_COMMAND_INT)
#: a COMMAND_LONG's and a COMMAND_INT's ``command`` field: payload bytes 28..29 (both messages).
_COMMAND_OFFSET = 28
_CRITICAL_COMMANDS = frozenset({
    M.MAV_CMD_COMPONENT_ARM_DISARM, M.MAV_CMD_DO_SET_MODE, M.MAV_CMD_NAV_LAND, M.MAV_CMD_NAV_RETURN_TO_LAUNCH,
})  # fmt: skip
_REQUEST_COMMANDS = frozenset({
    M.MAV_CMD_REQUEST_MESSAGE, M.MAV_CMD_SET_MESSAGE_INTERVAL, M.MAV_CMD_GET_HOME_POSITION,
    M.MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES,
})  # fmt: skip
_CLASS_OF_ID: dict[int, int] = {
    M.MAVLINK_MSG_ID_SET_MODE: CRITICAL,
    M.MAVLINK_MSG_ID_HEARTBEAT: HEARTBEAT,
    **dict.fromkeys((
        M.MAVLINK_MSG_ID_SET_POSITION_TARGET_LOCAL_NED, M.MAVLINK_MSG_ID_SET_POSITION_TARGET_GLOBAL_INT,
        M.MAVLINK_MSG_ID_PARAM_SET, M.MAVLINK_MSG_ID_MISSION_COUNT, M.MAVLINK_MSG_ID_MISSION_ITEM,
        M.MAVLINK_MSG_ID_MISSION_ITEM_INT, M.MAVLINK_MSG_ID_MISSION_CLEAR_ALL, M.MAVLINK_MSG_ID_MISSION_SET_CURRENT,
        M.MAVLINK_MSG_ID_MISSION_ACK, M.MAVLINK_MSG_ID_SETUP_SIGNING,
    ), COMMAND),
    **dict.fromkeys((
        M.MAVLINK_MSG_ID_PARAM_REQUEST_LIST, M.MAVLINK_MSG_ID_PARAM_REQUEST_READ, M.MAVLINK_MSG_ID_MISSION_REQUEST_LIST,
        M.MAVLINK_MSG_ID_MISSION_REQUEST, M.MAVLINK_MSG_ID_MISSION_REQUEST_INT, M.MAVLINK_MSG_ID_REQUEST_DATA_STREAM,
        M.MAVLINK_MSG_ID_FILE_TRANSFER_PROTOCOL,
    ), REQUEST),
}  # fmt: skip


def _packet_class(msg_id: int, payload_at: int, end: int, data: bytes) -> int:
    if msg_id in _COMMANDS:
        at = payload_at + _COMMAND_OFFSET
        # MAVLink 2 trims a payload's trailing zero bytes: a missing byte is 0
        command = (data[at] if at < end else 0) | ((data[at + 1] if at + 1 < end else 0) << 8)
        if command in _CRITICAL_COMMANDS:
            return CRITICAL
        return REQUEST if command in _REQUEST_COMMANDS else COMMAND
    return _CLASS_OF_ID.get(msg_id, OTHER)


def classify(data: bytes) -> int:
    """The class of a datagram: that of its most important packet (headers only; see the module
    docstring). Bytes that do not start a MAVLink frame are ``OTHER``."""
    best = OTHER
    i, size = 0, len(data)
    for _ in range(_MAX_PACKETS):
        if i >= size:
            break
        magic = data[i]
        if magic == _V2 and i + 10 <= size:
            end = i + 12 + data[i + 1] + (13 if data[i + 2] & 1 else 0)
            cls = _packet_class(data[i + 7] | data[i + 8] << 8 | data[i + 9] << 16, i + 10, min(size, i + 10 + data[i + 1]), data)
        elif magic == _V1 and i + 6 <= size:
            end = i + 8 + data[i + 1]
            cls = _packet_class(data[i + 5], i + 6, min(size, i + 6 + data[i + 1]), data)
        else:
            break
        best = min(best, cls)
        if best == CRITICAL:
            break
        i = end
    return best


T = TypeVar("T")


@dataclass
class IntakeCounters:
    """Per class (indexed as :data:`CLASS_NAMES`): datagrams queued, handled, handled in a later
    period than the one they arrived in (deferred), and dropped from a full queue; the most that
    waited at once, and the most periods one waited."""

    queued: list[int] = field(default_factory=lambda: [0] * len(CLASS_NAMES))
    handled: list[int] = field(default_factory=lambda: [0] * len(CLASS_NAMES))
    deferred: list[int] = field(default_factory=lambda: [0] * len(CLASS_NAMES))
    dropped: list[int] = field(default_factory=lambda: [0] * len(CLASS_NAMES))
    max_depth: int = 0
    max_wait_periods: int = 0

    def as_dict(self) -> dict[str, object]:
        """For the FC's exit summary: totals, and each class's figures where any is not 0."""
        by_class = {
            name: {"queued": q, "handled": h, "deferred": d, "dropped": x}
            for name, q, h, d, x in zip(CLASS_NAMES, self.queued, self.handled, self.deferred, self.dropped)
            if q or h or d or x
        }  # fmt: skip
        return {
            "queued": sum(self.queued), "handled": sum(self.handled), "deferred": sum(self.deferred),
            "dropped": sum(self.dropped), "max_depth": self.max_depth, "max_wait_periods": self.max_wait_periods,
            "by_class": by_class,
        }  # fmt: skip


class Intake(Generic[T]):
    """Bounded queues of items (a datagram and what the caller needs to handle it), one per class.

    :meth:`put` files an item under its class and period; :meth:`pop` gives the most important
    oldest one (counting it deferred if it arrived in an earlier period than ``period``)."""

    def __init__(self, capacity: int = DEFAULT_CAPACITY) -> None:
        if capacity < 1:
            raise ValueError(f"capacity must be >= 1, got {capacity!r}")
        self.capacity = capacity
        self._queues: tuple[deque[tuple[int, T]], ...] = tuple(deque() for _ in CLASS_NAMES)
        self._size = 0
        self.counters = IntakeCounters()

    def __len__(self) -> int:
        return self._size

    def put(self, cls: int, item: T, period: int) -> None:
        """Queue ``item`` of class ``cls`` that arrived in ``period``; when full, drop the oldest
        item of the least important class queued (which may be this one's own class)."""
        c = self.counters
        self._queues[cls].append((period, item))
        c.queued[cls] += 1
        self._size += 1
        if self._size > self.capacity:
            for low in range(len(CLASS_NAMES) - 1, -1, -1):
                q = self._queues[low]
                if q:
                    q.popleft()
                    c.dropped[low] += 1
                    self._size -= 1
                    break
        if self._size > c.max_depth:
            c.max_depth = self._size

    def pop(self, period: int) -> T | None:
        """The most important, oldest item (None: empty)."""
        for cls, q in enumerate(self._queues):
            if q:
                arrived, item = q.popleft()
                self._size -= 1
                c = self.counters
                c.handled[cls] += 1
                if arrived < period:
                    c.deferred[cls] += 1
                    c.max_wait_periods = max(c.max_wait_periods, period - arrived)
                return item
        return None

    def drop_all(self) -> None:
        """Drop everything queued (counted), e.g. at the end of a run."""
        for cls, q in enumerate(self._queues):
            self.counters.dropped[cls] += len(q)
            q.clear()
        self._size = 0
