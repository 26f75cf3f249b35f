"""A bad network acted out on one link: :class:`LinkImpairer`, the adapter between a link and two
:class:`smcpilot.impair.Impairer` streams (one for what it sends, one for what it receives).

Datagrams are offered with their address at ``monotonic_s()`` (s) and handed on when the impairer
releases them: sent ones to the socket's ``sendto``, received ones back to the link for parsing.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable

from smcpilot.impair import Impairer, LinkImpairment
from smcpilot.udplink.endpoint import Address

__all__ = ["LinkImpairer"]

Datagram = tuple[bytes, Address]


class LinkImpairer:
    """Both directions of an impaired link; streams seeded ``2 * seed + 1`` (tx) and ``2 * seed + 2`` (rx)."""

    __slots__ = ("tx", "rx", "_monotonic_s", "_sendto")

    def __init__(
        self,
        impairment: LinkImpairment,
        seed: int,
        *,
        monotonic_s: Callable[[], float],
        sendto: Callable[[bytes, Address], None],
    ) -> None:
        self.tx: Impairer[Datagram] = Impairer(impairment, 2 * seed + 1)
        self.rx: Impairer[Datagram] = Impairer(impairment, 2 * seed + 2)
        self._monotonic_s = monotonic_s
        self._sendto = sendto

    @classmethod
    def for_link(
        cls,
        impairment: LinkImpairment | None,
        seed: int,
        *,
        monotonic_s: Callable[[], float],
        sendto: Callable[[bytes, Address], None],
    ) -> LinkImpairer | None:
        """An impairer for an active ``impairment``; None for none (the link then sends straight)."""
        if impairment is None or not impairment.active:
            return None
        return cls(impairment, seed, monotonic_s=monotonic_s, sendto=sendto)

    def send(self, datagram: bytes, addr: Address) -> None:
        """Offer one datagram for ``addr`` to the sending stream, then send whatever is due."""
        now_s = self._monotonic_s()
        tx = self.tx
        tx.offer((datagram, addr), now_s)
        sendto = self._sendto
        for held, to in tx.due(now_s):
            sendto(held, to)

    def pump(self) -> None:
        """Send the held datagrams whose time has come."""
        tx = self.tx
        if tx.pending:
            sendto = self._sendto
            for held, to in tx.due(self._monotonic_s()):
                sendto(held, to)

    def receive(self, datagrams: Iterable[Datagram], now_s: float) -> list[Datagram]:
        """Offer datagrams just taken off the socket at ``now_s`` (s); return those released now."""
        rx = self.rx
        for item in datagrams:
            rx.offer(item, now_s)
        return rx.due(now_s)

    def wait_s(self) -> float:
        """Seconds until a held datagram is due, either direction (``inf``: none held)."""
        now_s = self._monotonic_s()
        return min(self.tx.wait_s(now_s), self.rx.wait_s(now_s))

    @property
    def counters(self) -> dict[str, dict[str, int]]:
        """What the impairment did, per direction."""
        return {"tx": self.tx.counters.as_dict(), "rx": self.rx.counters.as_dict()}
