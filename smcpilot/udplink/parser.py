"""What a link receives, as messages: :class:`DatagramParser` turns one datagram into its good,
checked messages.

Every datagram is parsed completely and on its own (a datagram holds whole packets, so no parser
state is carried from one datagram, or one peer, to the next). Bad bytes never raise: they are
dropped and counted, and the parser resynchronises on the next start-of-frame byte inside the same
datagram, so a good packet behind garbage still arrives. Packets from a system other than
``accept_system``, and (while signing has a key) unsigned packets not accepted unsigned, bad
signatures and old or out-of-window timestamps, are dropped and counted. The control loop's
messages are decoded by :mod:`smcpilot.fastcodec`; everything else by pymavlink.
"""

from __future__ import annotations

import re
import struct
from collections.abc import Callable

from pymavlink.dialects.v20 import ardupilotmega as mavlink

from smcpilot import fastcodec
from smcpilot import signing as _signing
from smcpilot.signing import Signing
from smcpilot.udplink.counters import LinkCounters
from smcpilot.udplink.endpoint import Address
from smcpilot.udplink.logtap import LogTap, log_copy

__all__ = ["DatagramParser", "Received"]

#: Messages with the address they came from, in arrival order.
Received = list[tuple[mavlink.MAVLink_message, Address]]

_MAGIC_V1 = mavlink.PROTOCOL_MARKER_V1
_MAGIC_V2 = mavlink.PROTOCOL_MARKER_V2
_START_OF_FRAME = re.compile(b"[\xfd\xfe]")
_SIGNATURE_BYTES = mavlink.MAVLINK_SIGNATURE_BLOCK_LEN
_DECODE_ERRORS = (mavlink.MAVError, struct.error, ArithmeticError, LookupError, TypeError, ValueError)
_UNKNOWN_MESSAGE = mavlink.MAVLink_unknown
_SIGNING_OK = _signing.OK
_REJECT_COUNTERS = _signing.REJECT_REASONS


class DatagramParser:
    """Parses datagrams for one link: counts into ``counters``, checks with ``signing``, logs the
    good packets to ``tap`` (stamped once per datagram).

    After each :meth:`parse_into`, :attr:`signed` says whether a signed packet was accepted (the
    link then pins the sender as a peer).
    """

    __slots__ = ("counters", "signed", "_decoders", "_accept_system", "_signing", "_accept_unsigned", "_tlog", "_clock_us", "_decode")

    def __init__(
        self,
        counters: LinkCounters,
        *,
        accept_system: int | None = None,
        signing: Signing | None = None,
        accept_unsigned: frozenset[int] | None = None,
        tap: LogTap | None = None,
        fast_codec: bool = True,
    ) -> None:
        self.counters = counters
        self.signed = False
        self._decoders = dict(fastcodec.DECODERS) if fast_codec else {}
        self._accept_system = accept_system
        self._signing = signing
        self._accept_unsigned = accept_unsigned
        self._tlog = tap.tlog if tap is not None else None
        self._clock_us = tap.clock_us if tap is not None else None
        self._decode = mavlink.MAVLink(None).decode  # decode() only: stateless without signing

    def parse_into(self, data: bytes, addr: Address, received: Received) -> int:
        """Append the good messages of one datagram from ``addr`` to ``received``; return how many."""
        self.signed = False
        counters = self.counters
        decoders = self._decoders
        accept_system = self._accept_system
        tlog = self._tlog
        signing = self._signing
        stamp_us = -1
        accepted = 0
        in_bad_run = False
        decoder: Callable[[bytes], mavlink.MAVLink_message | None] | None = None
        src_system = -1
        size = len(data)
        i = 0
        while i < size:
            magic = data[i]
            end = -1
            if magic == _MAGIC_V2:
                if i + 10 <= size:
                    flags = data[i + 2]
                    if not flags & ~1:  # only the "signed" incompat flag is defined
                        end = i + 12 + data[i + 1] + (_SIGNATURE_BYTES if flags else 0)
                        src_system = data[i + 5]
                        decoder = None if flags else decoders.get(data[i + 7] | (data[i + 8] << 8) | (data[i + 9] << 16))
            elif magic == _MAGIC_V1:
                if i + 6 <= size:
                    end = i + 8 + data[i + 1]
                    src_system = data[i + 3]
                    decoder = None
            if 0 <= end <= size:
                packet = data[i:end]
                if decoder is not None:
                    msg = decoder(packet)
                else:
                    try:
                        msg = self._decode(bytearray(packet))
                    except _DECODE_ERRORS:
                        msg = None
                    else:
                        if isinstance(msg, _UNKNOWN_MESSAGE):  # framed, but not in our dialect
                            counters.rx_unknown += 1
                            in_bad_run = False
                            i = end
                            continue
                if msg is not None:
                    in_bad_run = False
                    i = end
                    if accept_system is not None and src_system != accept_system:
                        counters.rx_foreign_system += 1
                        continue
                    if signing is not None and signing.enabled:
                        mid = packet[7] | packet[8] << 8 | packet[9] << 16 if magic == _MAGIC_V2 else packet[5]
                        verdict = signing.check(packet, mid, self._accept_unsigned)
                        if verdict != _SIGNING_OK:
                            name = _REJECT_COUNTERS[verdict]
                            setattr(counters, name, getattr(counters, name) + 1)
                            continue
                        if packet[2] & 1 and magic == _MAGIC_V2:
                            msg._signed = True
                            msg._link_id = packet[-13]
                            self.signed = True
                    received.append((msg, addr))
                    accepted += 1
                    if tlog is not None:
                        if stamp_us < 0:
                            stamp_us = self._clock_us()  # type: ignore[misc]
                        tlog.write(stamp_us, log_copy(packet))
                    continue
            # Not a good packet at i: count the run once and resynchronise on the next
            # start-of-frame byte after i.
            if not in_bad_run:
                counters.rx_bad += 1
                in_bad_run = True
            found = _START_OF_FRAME.search(data, i + 1)
            i = found.start() if found is not None else size
        counters.rx_messages += accepted
        return accepted
