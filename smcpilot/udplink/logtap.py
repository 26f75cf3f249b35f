"""The tlog's copy of a link's traffic: :class:`LogTap` and :func:`log_copy`.

Every packet is written as it went on the wire, stamped with the injected ``clock_us()`` (µs;
simulated time in lockstep, so logs are reproducible bit for bit), except a ``SETUP_SIGNING``,
which is written with its key zeroed. The tlog belongs to the link's owner: it is never closed here.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence

from pymavlink.dialects.v20 import ardupilotmega as mavlink

from smcpilot.signing import redact_setup_signing
from smcpilot.tlog import TlogWriter

__all__ = ["LogTap", "log_copy", "wall_clock_us"]

_MAGIC_V2 = mavlink.PROTOCOL_MARKER_V2
_SETUP_SIGNING_LOW = mavlink.MAVLINK_MSG_ID_SETUP_SIGNING & 0xFF  # id 256: low byte 0, middle byte 1


def wall_clock_us() -> int:
    """Wall-clock time, µs since the epoch (the default stamp of a link's tlog records)."""
    return time.time_ns() // 1000


def log_copy(packet: bytes) -> bytes:
    """What the tlog gets of a packet: itself, or a SETUP_SIGNING with its key zeroed."""
    if len(packet) > 9 and packet[7] == _SETUP_SIGNING_LOW and packet[8] == 1 and packet[0] == _MAGIC_V2:
        return redact_setup_signing(packet)
    return packet


class LogTap:
    """Writes the packets a link sends or receives to ``tlog``, stamped with ``clock_us()`` (µs)."""

    __slots__ = ("tlog", "clock_us")

    def __init__(self, tlog: TlogWriter, clock_us: Callable[[], int] = wall_clock_us) -> None:
        self.tlog = tlog
        self.clock_us = clock_us

    def write(self, packets: Sequence[bytes]) -> None:
        """Log ``packets`` (sent together) with one timestamp, each through :func:`log_copy`."""
        for packet in packets:
            if len(packet) > 9 and packet[7] == _SETUP_SIGNING_LOW and packet[8] == 1:
                packets = [log_copy(p) for p in packets]
                break
        self.tlog.write_many(self.clock_us(), packets)
