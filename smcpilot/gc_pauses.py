"""The garbage collector's passes over a stretch of a loop, timed: how many per generation, how long
in all, the longest, and the long ones with their (monotonic) start times, to line up with a real-time
loop's late ticks.

Installed with ``with GcPauses() as pauses:`` (``gc.callbacks``): two calls of a small function
per collection, nothing per tick.
"""

from __future__ import annotations

import gc
import time
from collections.abc import Callable
from types import TracebackType

__all__ = ["GcPauses"]


class GcPauses:
    """Time every collection while installed (a context manager; installing twice is an error).

    ``long`` holds the collections of ``keep_s`` or more as (start, duration) in seconds of
    ``clock`` (``time.monotonic``: the same clock in every process of the machine), the first
    ``cap`` of them.
    """

    def __init__(self, clock: Callable[[], float] = time.monotonic, *, keep_s: float = 0.0005, cap: int = 1000) -> None:
        self._clock = clock
        self.keep_s = keep_s
        self.cap = cap
        #: collections per generation (0, 1, 2)
        self.counts = [0, 0, 0]
        self.total_s = 0.0
        self.max_s = 0.0
        self.long: list[tuple[float, float]] = []
        self._t0 = 0.0

    def _callback(self, phase: str, info: dict) -> None:
        if phase == "start":
            self._t0 = self._clock()
            return
        d = self._clock() - self._t0
        gen = info.get("generation", 2)
        if 0 <= gen < 3:
            self.counts[gen] += 1
        self.total_s += d
        if d > self.max_s:
            self.max_s = d
        if d >= self.keep_s and len(self.long) < self.cap:
            self.long.append((self._t0, d))

    def __enter__(self) -> GcPauses:
        if self._callback in gc.callbacks:
            raise RuntimeError("GcPauses is installed already")
        gc.callbacks.append(self._callback)
        return self

    def __exit__(self, et: type[BaseException] | None, ev: BaseException | None, tb: TracebackType | None) -> None:
        try:
            gc.callbacks.remove(self._callback)
        except ValueError:  # removed by someone else: nothing to undo
            pass

    def summary(self) -> dict:
        """Counts, total and longest pause (s), and the long passes as two lists (start s, pause s)."""
        return {
            "collections": list(self.counts),
            "total_s": round(self.total_s, 6),
            "max_s": round(self.max_s, 6),
            "long_at_s": [round(t, 6) for t, _ in self.long],
            "long_s": [round(d, 6) for _, d in self.long],
        }
