"""Who a link sends to: :class:`PeerTable`, the initial destination and the peers heard from.

A peer is an address that wrote good packets to us; it stays a destination until it has been
silent for ``timeout_s`` seconds (real time, ``monotonic_s``: peers come and go in the real
world). The table is bounded (``max_peers``); pinned peers (a signed packet or a command came
from them) are never evicted by a newcomer.
"""

from __future__ import annotations

import math
from collections.abc import Callable

from smcpilot.udplink.counters import LinkCounters
from smcpilot.udplink.endpoint import Address

__all__ = ["PeerTable", "DEFAULT_PEER_TIMEOUT_S", "DEFAULT_MAX_PEERS", "PEER_QUIET_S"]

#: A peer that has not written for this long (s) stops receiving what the link sends to its peers.
DEFAULT_PEER_TIMEOUT_S = 10.0
#: At most this many peers learnt from incoming traffic are remembered (the initial destination
#: of an ``out`` endpoint comes on top); a flood of new source addresses cannot make us send to
#: more places than this. When full, the peer heard from least recently is forgotten.
DEFAULT_MAX_PEERS = 16
#: When the peer table is full, a peer (not pinned) silent this long (s) gives its place to a new
#: one; a station writing its 1 Hz heartbeat never is.
PEER_QUIET_S = 2.5


class PeerTable:
    """The destinations of a link's sends to "every peer".

    :attr:`destinations` is the initial destination (if any), then every remembered peer in the
    order first heard; it is rebuilt only when the table changes, so a send reads one attribute.
    :attr:`next_prune_s` is the ``monotonic_s`` time (s) at which a peer may have expired: a
    sender prunes (:meth:`prune`) when it has passed.
    """

    __slots__ = (
        "initial", "seen_s", "pinned", "destinations", "next_prune_s",
        "_timeout_s", "_max_peers", "_monotonic_s", "_counters", "_others_turn",
    )  # fmt: skip

    def __init__(
        self,
        initial: Address | None,
        *,
        timeout_s: float,
        max_peers: int,
        monotonic_s: Callable[[], float],
        counters: LinkCounters,
    ) -> None:
        #: the initial destination of an ``out`` endpoint: never expires.
        self.initial = initial
        #: peer -> ``monotonic_s`` time (s) it was last heard.
        self.seen_s: dict[Address, float] = {}
        #: addresses that sent signed packets or commands: a flood of new addresses never
        #: evicts them from the table (they still expire after ``timeout_s`` of silence).
        self.pinned: set[Address] = set()
        self.destinations: tuple[Address, ...] = ()
        self.next_prune_s = math.inf
        self._timeout_s = float(timeout_s)
        self._max_peers = max_peers
        self._monotonic_s = monotonic_s
        self._counters = counters
        #: where the next :meth:`limited` call starts among the peers not pinned.
        self._others_turn = 0
        self._rebuild()

    def current(self) -> tuple[Address, ...]:
        """:attr:`destinations`, after forgetting the peers silent for ``timeout_s``."""
        if self.next_prune_s <= self._monotonic_s():
            self.prune()
        return self.destinations

    def heard(self, addr: Address, now_s: float, signed: bool = False) -> None:
        """A good datagram from ``addr`` at ``now_s``: refresh (or add) its entry; pin it if ``signed``."""
        seen = self.seen_s
        if addr in seen:
            seen[addr] = now_s
        else:
            self.add(addr, now_s)
        if signed and addr in seen:
            self.pinned.add(addr)

    def pin(self, addr: Address) -> None:
        """Keep ``addr`` (a station that sent a command): new addresses never evict it, only its
        own silence for ``timeout_s`` does."""
        if addr in self.seen_s:
            self.pinned.add(addr)
        else:
            self.add(addr, self._monotonic_s(), pin=True)

    def add(self, addr: Address, now_s: float, *, pin: bool = False) -> None:
        """Remember a new peer heard at ``now_s``, making room if the table is full (see the class)."""
        seen = self.seen_s
        if len(seen) >= self._max_peers:
            if self.next_prune_s <= now_s:  # (a flood calls this per datagram: prune only when due)
                self.prune()
            if len(seen) >= self._max_peers:
                # Full. Pinned peers (signed packets, commands) are never evicted by a newcomer;
                # of the others, one silent for PEER_QUIET_S (it missed its 1 Hz heartbeat: gone
                # or going) makes room, so short-lived clients cannot lock new ones out. A peer
                # that keeps writing keeps its place: a flood of new addresses is not remembered
                # (its messages are still returned) and cannot evict the stations already known.
                pinned = self.pinned
                candidates = [a for a in seen if a not in pinned]
                victim: Address | None = None
                if candidates:
                    oldest = min(candidates, key=seen.__getitem__)
                    if pin or now_s - seen[oldest] >= PEER_QUIET_S:
                        victim = oldest
                self._counters.peers_rejected += 1
                if victim is None:
                    return
                del seen[victim]
        seen[addr] = now_s
        if pin:
            self.pinned.add(addr)
        self.next_prune_s = min(self.next_prune_s, now_s + self._timeout_s)
        self._rebuild()

    def prune(self) -> None:
        """Forget the peers silent for ``timeout_s`` (the initial destination stays)."""
        seen = self.seen_s
        now_s = self._monotonic_s()
        oldest_allowed_s = now_s - self._timeout_s
        stale = [addr for addr, seen_s in seen.items() if seen_s < oldest_allowed_s]
        for addr in stale:
            del seen[addr]
            self.pinned.discard(addr)
        self.next_prune_s = min(seen.values()) + self._timeout_s if seen else math.inf
        if stale:
            self._rebuild()

    def limited(self, others_limit: int) -> tuple[list[Address], int]:
        """The initial destination, the pinned peers, and ``others_limit`` of the other peers from
        where the last call stopped; and how many others were left out."""
        dests = self.current()
        initial, pinned = self.initial, self.pinned
        out = [a for a in dests if a == initial or a in pinned]
        others = [a for a in dests if a != initial and a not in pinned]
        n = len(others)
        if n <= others_limit:
            return out + others, 0
        start = self._others_turn % n
        self._others_turn = start + others_limit
        out.extend(others[(start + k) % n] for k in range(others_limit))
        return out, n - others_limit

    def _rebuild(self) -> None:
        initial = self.initial
        learnt = tuple(addr for addr in self.seen_s if addr != initial)
        self.destinations = ((initial,) if initial is not None else ()) + learnt
