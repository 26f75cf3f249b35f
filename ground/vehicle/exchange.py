"""What the request/reply exchanges (commands, parameters, missions) share: waiting for a
matching reply, and the vehicle's reason for a refusal."""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import TYPE_CHECKING

from pymavlink.dialects.v20 import ardupilotmega as mavlink

from ground.vehicle.telemetry import StatusText

if TYPE_CHECKING:
    from ground.vehicle.link import Link
    from ground.vehicle.subscription import Subscription

__all__ = ["await_match", "refusal_reason"]


def await_match(
    sub: Subscription, match: Callable[[mavlink.MAVLink_message], bool], timeout_s: float
) -> mavlink.MAVLink_message | None:
    """The first message of ``sub`` for which ``match`` holds, waiting up to ``timeout_s`` wall
    seconds in all; None if none came."""
    deadline = time.monotonic() + timeout_s
    while (remaining := deadline - time.monotonic()) > 0:
        msg = sub.get(remaining)
        if msg is None:
            return None
        if match(msg):
            return msg
    return None


def refusal_reason(link: Link, sub: Subscription, texts: list[StatusText], grace_s: float = 0.3) -> str | None:
    """The vehicle's explanation of a refusal: the most severe recent STATUSTEXT that came
    with it (``texts``, collected from ``sub``; waiting ``grace_s`` wall seconds for one if none
    has come yet). ``link`` stamps late texts with the vehicle's simulated time."""
    deadline = time.monotonic() + grace_s
    while not texts:
        remaining = deadline - time.monotonic()
        if remaining <= 0:
            break
        msg = sub.get(remaining)
        if msg is not None and msg.get_type() == "STATUSTEXT":
            texts.append(StatusText.received(msg, link.sim_time_s))
    if not texts:
        return None
    serious = [t for t in texts if t.severity <= mavlink.MAV_SEVERITY_WARNING]
    return (serious or texts)[-1].text
