"""A progress line for a flight being logged: simulated time, speed against real time, ETA.

:class:`TlogFollower` reads the timestamps of the whole records appended to a growing ``.tlog``
(the flight controller hands records to the OS only as whole records, so the file always ends
on a record boundary); :class:`ProgressLine` prints, from a thread, one line from them.

On a terminal the line is redrawn in place (``\\r``, erase to end of line) a few times a second
and erased at the end; elsewhere (a CI log, a file) it is printed only when asked for, as a
plain line every ``plain_period_s`` wall seconds, so no control characters end up in a log.
"""

from __future__ import annotations

import os
import struct
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import TextIO

from smcpilot.tlog import TIMESTAMP_BYTES

__all__ = ["TlogFollower", "ProgressLine", "format_progress"]

_MAGIC_V2 = 0xFD
_MAGIC_V1 = 0xFE
_SIGNED = 0x01
_TIMESTAMP = struct.Struct(">Q")


class TlogFollower:
    """The latest record time of a ``.tlog`` another process is writing (µs; None before one)."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self._offset = 0
        self._pending = b""
        self.first_us: int | None = None
        self.last_us: int | None = None

    def poll(self) -> int | None:
        """Read what was appended since the last call; the latest record's time in µs."""
        try:
            with open(self.path, "rb") as f:
                f.seek(self._offset)
                chunk = f.read()
        except OSError:
            return self.last_us  # not created yet, or gone
        self._offset += len(chunk)
        data = self._pending + chunk
        i, n = 0, len(data)
        while n - i >= TIMESTAMP_BYTES + 3:
            magic, length = data[i + TIMESTAMP_BYTES], data[i + TIMESTAMP_BYTES + 1]
            if magic == _MAGIC_V2:
                total = 12 + length + (13 if data[i + TIMESTAMP_BYTES + 2] & _SIGNED else 0)
            elif magic == _MAGIC_V1:
                total = 8 + length
            else:  # not a log we can follow: stop reading it (the flight itself is not affected)
                self._offset, data, i = os.path.getsize(self.path), b"", 0
                break
            if n - i < TIMESTAMP_BYTES + total:
                break
            (t_us,) = _TIMESTAMP.unpack_from(data, i)
            if self.first_us is None:
                self.first_us = t_us
            self.last_us = t_us
            i += TIMESTAMP_BYTES + total
        self._pending = data[i:]
        return self.last_us


def format_progress(sim_s: float, wall_s: float, total_sim_s: float | None) -> str:
    """``sim 12.3/55.0 s (22 %)  12.9x real time  ETA 3 s`` (no ETA without a total)."""
    speed = sim_s / wall_s if wall_s > 0 else 0.0
    if total_sim_s:
        pct = min(100.0, 100.0 * sim_s / total_sim_s)
        text = f"sim {sim_s:6.1f}/{total_sim_s:g} s ({pct:3.0f} %)  {speed:5.1f}x real time"
        if speed > 0 and sim_s > 0:
            text += f"  ETA {max(0.0, (total_sim_s - sim_s) / speed):4.0f} s"
        return text
    return f"sim {sim_s:6.1f} s  {speed:5.1f}x real time"


class ProgressLine:
    """Show the progress of a flight logged to ``tlog`` on ``out`` until :meth:`stop`."""

    def __init__(
        self,
        tlog: Path,
        total_sim_s: float | None,
        out: TextIO,
        *,
        tty: bool | None = None,
        period_s: float = 0.25,
        plain_period_s: float = 5.0,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.follower = TlogFollower(tlog)
        self.total_sim_s = total_sim_s
        self.out = out
        self.tty = out.isatty() if tty is None else tty
        self.period_s = period_s if self.tty else plain_period_s
        self._clock = clock
        self._t0 = clock()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._loop, name="progress", daemon=True)
        self.lines_written = 0

    def start(self) -> ProgressLine:
        self._thread.start()
        return self

    def line(self) -> str | None:
        """The current progress text, None before the first record."""
        last = self.follower.poll()
        if last is None or self.follower.first_us is None:
            return None
        return format_progress((last - self.follower.first_us) * 1e-6, self._clock() - self._t0, self.total_sim_s)

    def _loop(self) -> None:
        while not self._stop.wait(self.period_s):
            text = self.line()
            if text is None:
                continue
            try:
                self.out.write(f"\r{text}\x1b[K" if self.tty else f"progress: {text}\n")
                self.out.flush()
            except (OSError, ValueError):
                return
            self.lines_written += 1

    def clear(self) -> None:
        """Erase the line on a terminal, before other output (it is redrawn at the next update)."""
        if self.tty and self.lines_written:
            try:
                self.out.write("\r\x1b[K")
                self.out.flush()
            except (OSError, ValueError):
                pass

    def stop(self) -> None:
        """Stop the thread and erase the line (on a terminal)."""
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join(timeout=2.0)
        self.clear()
