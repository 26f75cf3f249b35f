"""Injected clocks: control and physics code never read time from globals.

- :class:`SimClock` is advanced explicitly (lockstep: by the simulator's time stamps or by ticks);
- :class:`WallClock` reads ``time.monotonic`` scaled by a speed factor (real time).

Both give time in seconds as ``now_s()`` and in integer microseconds as ``now_us()`` (what log
time stamps and MAVLink ``time_usec`` fields need). A :class:`WallClock` also sleeps.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Protocol


class Clock(Protocol):
    def now_s(self) -> float: ...

    def now_us(self) -> int: ...


class SimClock:
    """Simulated time, set or advanced by its owner; integer microseconds are the truth."""

    __slots__ = ("_t_us",)

    def __init__(self, t_us: int = 0) -> None:
        self._t_us = int(t_us)

    def now_us(self) -> int:
        return self._t_us

    def now_s(self) -> float:
        return self._t_us * 1e-6

    def set_us(self, t_us: int) -> None:
        self._t_us = int(t_us)

    def advance_us(self, dt_us: int) -> None:
        self._t_us += int(dt_us)


class WallClock:
    """Monotonic wall time since construction, times ``speed`` (1 = real time)."""

    __slots__ = ("_t0", "_speed", "_mono")

    def __init__(self, speed: float = 1.0, monotonic: Callable[[], float] = time.monotonic) -> None:
        if not speed > 0.0:
            raise ValueError(f"clock speed must be > 0, got {speed!r}")
        self._mono = monotonic
        self._t0 = monotonic()
        self._speed = float(speed)

    def now_s(self) -> float:
        return (self._mono() - self._t0) * self._speed

    def now_us(self) -> int:
        return int((self._mono() - self._t0) * self._speed * 1e6)

    def wall_until(self, t_s: float) -> float:
        """Wall seconds until this clock reads ``t_s`` (negative if already past)."""
        return t_s / self._speed - (self._mono() - self._t0)
