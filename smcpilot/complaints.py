"""Bad input from a peer, counted by kind, with rate-limited messages naming it.

Shared by the servers of ``smcpilot sim --serve`` (:mod:`sim_bridge.serve`) and the flight
controller's PX4 simulator link (:mod:`fc.sim_px4`): the first piece of a kind is said at once,
then at most one message every ``every_s`` wall seconds, saying how many more came.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable


class Complaints:
    """Bad input: counted per kind; a message the first time a kind is seen, then at most one
    every ``every_s`` wall seconds saying how many more came."""

    def __init__(self, say: Callable[[str], None], prefix: str, clock: Callable[[], float] = time.monotonic, every_s: float = 5.0) -> None:
        self._say = say
        self._prefix = prefix
        self._clock = clock
        self._every_s = every_s
        self.counts: dict[str, int] = {}
        self._last_said = -math.inf
        self._unsaid = 0

    @property
    def total(self) -> int:
        return sum(self.counts.values())

    def bad(self, kind: str, text: str) -> None:
        """One piece of bad input of ``kind`` (e.g. ``short``), described by ``text``; dropped."""
        first = kind not in self.counts
        self.counts[kind] = self.counts.get(kind, 0) + 1
        now = self._clock()
        if first or now - self._last_said >= self._every_s:
            more = f" (and {self._unsaid} more bad since the last message)" if self._unsaid else ""
            self._say(f"{self._prefix}: dropped {text}; {self.total} bad so far{more}")
            self._last_said = now
            self._unsaid = 0
        else:
            self._unsaid += 1
