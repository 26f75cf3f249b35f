"""A link's traffic statistics: :class:`LinkCounters`, one object shared by all of a link's parts."""

from __future__ import annotations

from dataclasses import asdict, dataclass

__all__ = ["LinkCounters"]


@dataclass(slots=True)
class LinkCounters:
    """Traffic statistics of one link (mutable; read them, or ``reset()``).

    ``rx_unsigned``, ``rx_bad_signature``, ``rx_old_timestamp`` and ``rx_stream_window`` count
    good packets dropped by signing (:meth:`smcpilot.signing.Signing.check`).
    ``rx_bad`` counts runs of bytes that are not a good packet (garbage, a truncated packet, a
    bad CRC, bad header flags): a whole garbage datagram counts once, and a good packet ends a
    run. ``rx_unknown`` counts well-framed packets whose id the dialect does not know (their CRC
    cannot be checked). ``rx_foreign_system`` counts good packets dropped because their source
    system is not ``accept_system``. ``tx_messages`` counts messages encoded (each took a
    sequence number), ``tx_datagrams`` datagrams the OS accepted, ``tx_errors`` failed sends
    (unreachable peer, full buffer, ...), including ICMP refusals reported on a later receive.
    """

    rx_datagrams: int = 0
    rx_messages: int = 0
    rx_bad: int = 0
    rx_unknown: int = 0
    rx_foreign_system: int = 0
    tx_messages: int = 0
    tx_datagrams: int = 0
    tx_errors: int = 0
    #: errno of the most recent failed send, 0 if none.
    last_tx_errno: int = 0
    #: datagrams from a new address not remembered as a peer because ``max_peers`` were known
    #: (their messages are still returned by ``recv``), or peers forgotten to make room.
    peers_rejected: int = 0
    rx_unsigned: int = 0
    rx_bad_signature: int = 0
    rx_old_timestamp: int = 0
    rx_stream_window: int = 0

    @property
    def rx_rejected(self) -> int:
        """Every packet received and not returned: bad bytes, unknown ids, foreign systems, signing."""
        return (
            self.rx_bad + self.rx_unknown + self.rx_foreign_system + self.rx_unsigned + self.rx_bad_signature
            + self.rx_old_timestamp + self.rx_stream_window
        )  # fmt: skip

    @property
    def rx_signing_rejected(self) -> int:
        """Packets dropped by signing (unsigned, bad signature, old or out-of-window timestamp)."""
        return self.rx_unsigned + self.rx_bad_signature + self.rx_old_timestamp + self.rx_stream_window

    def as_dict(self) -> dict[str, int]:
        """A plain-dict snapshot."""
        return asdict(self)

    def reset(self) -> None:
        """Set every counter back to zero."""
        for name in self.__slots__:  # type: ignore[attr-defined]
            setattr(self, name, 0)
