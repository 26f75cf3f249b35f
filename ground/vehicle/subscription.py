"""Subscriptions: the messages of some types from the vehicle, as they arrive (see
:meth:`ground.vehicle.link.Link.subscribe`)."""

from __future__ import annotations

import logging
import queue
from collections.abc import Callable, Iterator
from typing import TYPE_CHECKING

from pymavlink.dialects.v20 import ardupilotmega as mavlink

if TYPE_CHECKING:
    from ground.vehicle.link import Link

__all__ = ["Subscription"]

log = logging.getLogger(__name__)


class Subscription:
    """Messages of some types, as they arrive: into a queue (:meth:`get`) or to a callback.

    Callbacks run on the receiver thread: keep them short and never call blocking
    :class:`~ground.vehicle.Vehicle` methods from them. A full queue drops its oldest message
    (``dropped`` counts them). Use as a context manager, or :meth:`close`.
    """

    def __init__(
        self,
        vehicle: Link,
        types: frozenset[str] | None,
        callback: Callable[[mavlink.MAVLink_message], None] | None,
        maxsize: int,
    ) -> None:
        self._vehicle = vehicle
        self.types = types
        self.callback = callback
        self.queue: queue.Queue[mavlink.MAVLink_message] = queue.Queue(maxsize=maxsize)
        self.dropped = 0

    def wants(self, msg_type: str) -> bool:
        return self.types is None or msg_type in self.types

    def _deliver(self, msg: mavlink.MAVLink_message) -> None:
        if self.callback is not None:
            try:
                self.callback(msg)
            except Exception:  # a user's callback must not kill the receiver
                log.exception("subscription callback failed on %s", msg.get_type())
            return
        while True:
            try:
                self.queue.put_nowait(msg)
                return
            except queue.Full:
                try:
                    self.queue.get_nowait()
                    self.dropped += 1
                except queue.Empty:
                    pass

    def get(self, timeout_s: float | None = None) -> mavlink.MAVLink_message | None:
        """The next message, waiting up to ``timeout_s`` wall seconds (None: forever); None on timeout."""
        try:
            return self.queue.get(timeout=timeout_s)
        except queue.Empty:
            return None

    def __iter__(self) -> Iterator[mavlink.MAVLink_message]:
        """Messages already queued, without waiting."""
        while True:
            try:
                yield self.queue.get_nowait()
            except queue.Empty:
                return

    def close(self) -> None:
        self._vehicle._unsubscribe(self)

    def __enter__(self) -> Subscription:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
