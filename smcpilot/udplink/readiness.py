"""Which of a fixed set of sockets have something to read, asked many times a millisecond.

A swarm's processes (the simulator with a link per vehicle, an FC group with a link per flight
controller) poll the same sockets over and over while they busy-wait in lockstep. ``select`` hands
the whole set to the kernel on every call and the caller then searches it; ``epoll`` keeps the set
registered and returns only the ready ones. :class:`Readiness` uses ``epoll`` where there is one
(Linux), else ``select``; a closed socket simply stops being reported.
"""

from __future__ import annotations

import select
from collections.abc import Sequence

__all__ = ["Readiness"]


class Readiness:
    """The readable ones of the file descriptors given to :meth:`watch`. Close it (or use it as a
    context manager) when done: it holds a file descriptor of its own on Linux."""

    def __init__(self, fds: Sequence[int] = ()) -> None:
        self._fds: list[int] = []
        self._epoll: select.epoll | None = None
        if fds:
            self.watch(fds)

    def watch(self, fds: Sequence[int]) -> None:
        """Look at ``fds`` from now on (instead of the previous set)."""
        self.close()
        self._fds = list(fds)
        if hasattr(select, "epoll"):
            self._epoll = select.epoll(len(self._fds) or 1)
            for fd in self._fds:
                self._epoll.register(fd, select.EPOLLIN)

    def wait(self, timeout_s: float) -> list[int]:
        """The readable ones, waiting at most ``timeout_s`` (0: not at all) for one; in no given order."""
        ep = self._epoll
        if ep is None:
            return select.select(self._fds, (), (), max(0.0, timeout_s))[0]  # type: ignore[no-any-return]
        return [fd for fd, _ in ep.poll(max(0.0, timeout_s))]

    def close(self) -> None:
        if self._epoll is not None:
            self._epoll.close()
            self._epoll = None

    def __enter__(self) -> Readiness:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
