"""Link impairments: loss, delay, jitter, duplication, reordering and outages of UDP datagrams.

A :class:`LinkImpairment` describes what a bad network does to one link; an :class:`Impairer`
acts it out on a stream of datagrams. The impairer is pure: no sockets, no clock of its own (the
caller passes ``now_s``, any monotonic seconds), one seeded random stream
(:class:`random.Random`), so the same seed and the same sequence of calls give the same
decisions. :class:`smcpilot.link.MavlinkUdp` runs one impairer on what it sends and one on what it
receives when it is given an impairment (the flight controller impairs its simulator link and its
ground link this way, so both directions of each link are impaired by one process).

What happens to each datagram offered, in this order:

1. inside an outage window (``outage_at_s`` .. ``outage_at_s + outage_s`` after the first
   datagram) it is dropped;
2. it is dropped with probability ``loss``;
3. it is held for ``delay_ms`` plus a uniform jitter in ``[0, jitter_ms]``; with probability
   ``reorder`` it is held ``reorder_ms`` longer still, so that later datagrams overtake it;
4. with probability ``duplicate`` a second copy is released ``dup_gap_ms`` after the first.

Datagrams are released by :meth:`Impairer.due` once their time has come, in release-time order
(ties in offer order). Without delay, jitter or reordering a datagram is due at once.

Text form (command line ``--sim-link``/``--gcs-link``, scenario ``[link] sim = "..."``)::

    loss=0.2,delay_ms=4,jitter_ms=2,duplicate=0.01,reorder=0.05,seed=3
    outage_at_s=5,outage_s=0.5

"none" (or an empty string) is no impairment.
"""

from __future__ import annotations

import heapq
import math
import random
from dataclasses import dataclass, fields
from typing import Generic, TypeVar

from smcpilot.errors import ConfigError

__all__ = ["ImpairmentError", "LinkImpairment", "Impairer", "ImpairCounters", "parse_impairment"]

T = TypeVar("T")


class ImpairmentError(ConfigError):
    """A link impairment is invalid (the message names the key)."""


_PROBABILITIES = ("loss", "duplicate", "reorder")


@dataclass(frozen=True)
class LinkImpairment:
    """What a bad network does to the datagrams of one link (both directions, each its own stream).

    Probabilities are per datagram in [0, 1]; times are milliseconds of the clock the impairer is
    driven with (wall time on the processes' links), ``outage_*`` in seconds after the first
    datagram. ``seed`` None: derived from the scenario's seed by whoever builds the impairer.
    """

    loss: float = 0.0
    delay_ms: float = 0.0
    jitter_ms: float = 0.0
    duplicate: float = 0.0
    #: probability that a datagram is held back ``reorder_ms`` longer (later ones overtake it).
    reorder: float = 0.0
    reorder_ms: float = 2.0
    #: gap between a datagram and its duplicate.
    dup_gap_ms: float = 0.0
    #: a total outage starting this many seconds after the first datagram (None: no outage).
    outage_at_s: float | None = None
    outage_s: float = 0.0
    seed: int | None = None

    def __post_init__(self) -> None:
        for name in _PROBABILITIES:
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not (0.0 <= v <= 1.0):
                raise ImpairmentError(f"link impairment {name} must be a probability in [0, 1], got {v!r}")
        for name in ("delay_ms", "jitter_ms", "reorder_ms", "dup_gap_ms", "outage_s"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not (math.isfinite(v) and 0.0 <= v <= 60_000.0):
                raise ImpairmentError(f"link impairment {name} must be a number in [0, 60000], got {v!r}")
        if self.outage_at_s is not None and not (isinstance(self.outage_at_s, (int, float)) and math.isfinite(self.outage_at_s)
                                                 and self.outage_at_s >= 0.0):  # fmt: skip
            raise ImpairmentError(f"link impairment outage_at_s must be >= 0 s, got {self.outage_at_s!r}")
        if self.seed is not None and (isinstance(self.seed, bool) or not isinstance(self.seed, int) or self.seed < 0):
            raise ImpairmentError(f"link impairment seed must be a whole number >= 0, got {self.seed!r}")

    @property
    def active(self) -> bool:
        """True if it changes anything at all."""
        return bool(self.loss or self.delay_ms or self.jitter_ms or self.duplicate or self.reorder
                    or (self.outage_at_s is not None and self.outage_s > 0))  # fmt: skip

    @property
    def holds(self) -> bool:
        """True if datagrams may be held back (the owner must call :meth:`Impairer.due` on time)."""
        return bool(self.delay_ms or self.jitter_ms or self.reorder or (self.duplicate and self.dup_gap_ms))

    def to_text(self) -> str:
        """The text form :func:`parse_impairment` reads back (only the keys that differ from the default)."""
        default = LinkImpairment()
        parts = [f"{f.name}={getattr(self, f.name):g}" if isinstance(getattr(self, f.name), float) else f"{f.name}={getattr(self, f.name)}"
                 for f in fields(self) if getattr(self, f.name) != getattr(default, f.name)]  # fmt: skip
        return ",".join(parts) if parts else "none"

    def to_mapping(self) -> dict[str, float | int]:
        default = LinkImpairment()
        return {f.name: getattr(self, f.name) for f in fields(self) if getattr(self, f.name) != getattr(default, f.name)}

    @classmethod
    def from_mapping(cls, doc: object, where: str = "link") -> LinkImpairment:
        """From a TOML table (or its text form as a string)."""
        if isinstance(doc, str):
            return parse_impairment(doc, where)
        if not isinstance(doc, dict):
            raise ImpairmentError(f"{where} must be a table or a string like \"loss=0.2,delay_ms=4\", got {doc!r}")
        known = {f.name for f in fields(cls)}
        unknown = sorted(set(doc) - known)
        if unknown:
            raise ImpairmentError(f"{where}: unknown key {unknown[0]!r} (known: {', '.join(sorted(known))})")
        kw: dict[str, object] = {}
        for key, value in doc.items():
            if key == "seed":
                kw[key] = value
            elif isinstance(value, bool) or not isinstance(value, (int, float)):
                raise ImpairmentError(f"{where}.{key} must be a number, got {value!r}")
            else:
                kw[key] = float(value)
        try:
            return cls(**kw)  # type: ignore[arg-type]
        except ImpairmentError as exc:
            raise ImpairmentError(f"{where}: {exc}") from None


def parse_impairment(text: str, where: str = "link impairment") -> LinkImpairment:
    """``"loss=0.2,delay_ms=4"`` -> :class:`LinkImpairment`; "none" or "" -> no impairment."""
    text = text.strip()
    if text.lower() in ("", "none"):
        return LinkImpairment()
    known = {f.name for f in fields(LinkImpairment)}
    kw: dict[str, object] = {}
    for item in text.split(","):
        key, sep, value = item.partition("=")
        key = key.strip()
        if not sep or key not in known:
            hint = f"unknown key {key!r}" if sep else f"expected KEY=VALUE, got {item.strip()!r}"
            raise ImpairmentError(f"{where}: {hint} (keys: {', '.join(f.name for f in fields(LinkImpairment))})")
        try:
            kw[key] = int(value) if key == "seed" else float(value)
        except ValueError:
            raise ImpairmentError(f"{where}: {key} must be a number, got {value.strip()!r}") from None
    try:
        return LinkImpairment(**kw)  # type: ignore[arg-type]
    except ImpairmentError as exc:
        raise ImpairmentError(f"{where}: {exc}") from None


@dataclass(slots=True)
class ImpairCounters:
    """What an impairer did: datagrams offered, dropped (loss and outage), duplicated, reordered."""

    offered: int = 0
    lost: int = 0
    outage_dropped: int = 0
    duplicated: int = 0
    reordered: int = 0
    released: int = 0

    def as_dict(self) -> dict[str, int]:
        return {name: getattr(self, name) for name in self.__slots__}  # type: ignore[attr-defined]


class Impairer(Generic[T]):
    """Acts out a :class:`LinkImpairment` on items (datagrams with their address) with injected time."""

    def __init__(self, spec: LinkImpairment, seed: int) -> None:
        self.spec = spec
        self._rng = random.Random(spec.seed if spec.seed is not None else seed)
        self._queue: list[tuple[float, int, T]] = []
        self._n = 0
        self._t0: float | None = None
        self.counters = ImpairCounters()

    def offer(self, item: T, now_s: float) -> None:
        """One datagram sent (or received) at ``now_s``: dropped, or queued for :meth:`due`."""
        spec = self.spec
        c = self.counters
        c.offered += 1
        if self._t0 is None:
            self._t0 = now_s
        rng = self._rng
        if spec.outage_at_s is not None and spec.outage_s > 0:
            since = now_s - self._t0
            if spec.outage_at_s <= since < spec.outage_at_s + spec.outage_s:
                c.outage_dropped += 1
                return
        if spec.loss and rng.random() < spec.loss:
            c.lost += 1
            return
        hold_ms = spec.delay_ms
        if spec.jitter_ms:
            hold_ms += rng.random() * spec.jitter_ms
        if spec.reorder and rng.random() < spec.reorder:
            hold_ms += spec.reorder_ms
            c.reordered += 1
        due = now_s + hold_ms * 1e-3
        self._push(due, item)
        if spec.duplicate and rng.random() < spec.duplicate:
            c.duplicated += 1
            self._push(due + spec.dup_gap_ms * 1e-3, item)

    def _push(self, due: float, item: T) -> None:
        heapq.heappush(self._queue, (due, self._n, item))
        self._n += 1

    def due(self, now_s: float) -> list[T]:
        """The items whose release time has come, in release order (removed from the queue)."""
        q = self._queue
        out: list[T] = []
        while q and q[0][0] <= now_s:
            out.append(heapq.heappop(q)[2])
        self.counters.released += len(out)
        return out

    @property
    def pending(self) -> int:
        """Items held back."""
        return len(self._queue)

    def wait_s(self, now_s: float) -> float:
        """Seconds until the next item is due (0 if one is due now, ``inf`` if none is held)."""
        return max(0.0, self._queue[0][0] - now_s) if self._queue else math.inf
