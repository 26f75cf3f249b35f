"""What a link sends, as bytes: :class:`Encoder` (sequence numbers, encoding, signing) and the
file-like objects pymavlink writes packed messages to (:class:`PacketWriter`, :class:`PacketSink`).

The three messages of the control loop (ATTITUDE, LOCAL_POSITION_NED, HIL_ACTUATOR_CONTROLS, and
the other types :mod:`smcpilot.fastcodec` packs) are encoded by :mod:`smcpilot.fastcodec` (same
bytes, several times faster); everything else goes through pymavlink.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

from pymavlink.dialects.v20 import ardupilotmega as mavlink

from smcpilot import fastcodec
from smcpilot.signing import Signing
from smcpilot.udplink.counters import LinkCounters

__all__ = ["Encoder", "PacketSink", "PacketWriter"]


class PacketSink:
    """The file pymavlink writes packed messages to, collecting them for one send (a stream link:
    PX4's simulator API over TCP, both sides)."""

    def __init__(self) -> None:
        self.parts: list[bytes] = []

    def write(self, data: bytes) -> None:
        self.parts.append(bytes(data))

    def take(self) -> bytes:
        """Everything written since the last take, joined."""
        data = b"".join(self.parts)
        self.parts.clear()
        return data


class PacketWriter:
    """File-like shim: each packet pymavlink's ``MAVLink.send`` writes goes to ``send_encoded``
    (so ``link.mav.<message>_send(...)`` sends through the link)."""

    __slots__ = ("_send_encoded",)

    def __init__(self, send_encoded: Callable[[bytes], None]) -> None:
        self._send_encoded = send_encoded

    def write(self, packet: bytes) -> None:
        self._send_encoded(packet)


class Encoder:
    """Sequence numbers, encoding and signing for one link.

    :attr:`mav` is the pymavlink encoder; its ``seq`` is the link's sequence counter, and every
    number taken counts one ``tx_messages``. Packets come out of :meth:`encode` unsigned: the
    link's send path signs them all in one place (:meth:`sign`, while :attr:`signing` has a key).
    """

    __slots__ = ("mav", "counters", "signing", "link_id", "_packers")

    def __init__(
        self,
        writer: PacketWriter | None,
        *,
        source_system: int,
        source_component: int,
        counters: LinkCounters,
        fast_codec: bool = True,
        signing: Signing | None = None,
        link_id: int = 0,
    ) -> None:
        self.mav = mavlink.MAVLink(writer, srcSystem=source_system, srcComponent=source_component)
        self.counters = counters
        #: the signing state (shared by the process's links; None: never signs).
        self.signing = signing
        #: the link id this link's signed packets carry (0..255).
        self.link_id = link_id
        self._packers = dict(fastcodec.PACKERS) if fast_codec else {}

    @property
    def source(self) -> tuple[int, int]:
        """(source system, source component) packets are sent as."""
        return self.mav.srcSystem, self.mav.srcComponent

    def take_seq(self) -> int:
        """The next sequence number, consumed (counted in ``tx_messages``)."""
        mav = self.mav
        seq = mav.seq
        mav.seq = (seq + 1) & 0xFF
        self.counters.tx_messages += 1
        return seq

    def encode(self, msg: mavlink.MAVLink_message) -> bytes:
        """``msg`` packed with the next sequence number (consumed, counted), not signed."""
        mav = self.mav
        seq = mav.seq
        packer = self._packers.get(type(msg))
        if packer is not None and not mav.signing.sign_outgoing:
            packet = packer(msg, seq, mav.srcSystem, mav.srcComponent)
        else:
            packet = msg.pack(mav)
        mav.seq = (seq + 1) & 0xFF
        self.counters.tx_messages += 1
        return packet

    def sign(self, packets: Sequence[bytes]) -> list[bytes]:
        """``packets`` signed with :attr:`link_id` (call only while :attr:`signing` is enabled)."""
        sign = self.signing.sign  # type: ignore[union-attr]
        link_id = self.link_id
        return [sign(p, link_id) for p in packets]
